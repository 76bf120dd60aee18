// The trainer: set-up (fresh weights or an --init model), the run loop,
// the model written; options and progress lines.
#include "digital_sun_sensor/train/trainer.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <iomanip>
#include <sstream>

#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/model/input_envelope.h"
#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/sparse/threads.h"
#include "digital_sun_sensor/train/sigma_calibration.h"
#include "digital_sun_sensor/train/value_saturation_choice.h"
#include "trainer_impl.h"

namespace dss {
namespace {

// The richest angle correction the trainer fits on its validation images
// (the degree is cross-validated: on the drawn masks A to I, none after two
// epochs of training, degree 1 on the heads as created).
constexpr int kHeldOutCorrectionMaxDegree = 8;

std::string formatNumber(double x) {
  std::ostringstream out;
  out << std::setprecision(3) << x;
  return out.str();
}

using Clock = std::chrono::steady_clock;
double secondsSince(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

}  // namespace

std::string formatProgress(const TrainProgress& p) {
  auto clock = [](double s) {
    char buf[32];
    const long t = std::lround(std::max(0.0, s));
    std::snprintf(buf, sizeof(buf), "%ld:%02ld:%02ld", t / 3600, (t / 60) % 60, t % 60);
    return std::string(buf);
  };
  char line[320];
  if (p.epoch_end) {
    std::snprintf(line, sizeof(line),
                  "epoch %d/%d done: loss %.4f, validation mean %.5f / %.5f deg, max %.4f / %.4f deg, class %.2f%%, "
                  "%lld gross (best %.5f deg at epoch %d); %.0f img/s, elapsed %s, ETA %s",
                  p.epoch + 1, p.epochs, p.loss, p.val_alpha_mean_deg, p.val_beta_mean_deg, p.val_alpha_max_deg,
                  p.val_beta_max_deg, 100.0 * p.val_class_accuracy, static_cast<long long>(p.val_gross),
                  p.best_val_mean_deg, p.best_epoch + 1, p.images_per_s, clock(p.elapsed_s).c_str(),
                  clock(p.eta_s).c_str());
  } else {
    std::snprintf(line, sizeof(line), "epoch %d/%d step %lld/%lld: loss %.4f, lr %.2e; %.0f img/s, elapsed %s, ETA %s",
                  p.epoch + 1, p.epochs, static_cast<long long>(p.step_in_epoch),
                  static_cast<long long>(p.steps_per_epoch), p.loss, p.learning_rate, p.images_per_s,
                  clock(p.elapsed_s).c_str(), clock(p.eta_s).c_str());
  }
  return line;
}

const char* toString(TrainStop stop) {
  switch (stop) {
    case TrainStop::finished:
      return "finished";
    case TrainStop::early_stopped:
      return "early_stopped";
    case TrainStop::time_limit:
      return "time_limit";
    case TrainStop::interrupted:
      return "interrupted";
  }
  return "unknown";
}

void TrainOptions::validate() const {
  auto require = [](bool ok, const std::string& what) {
    if (!ok) throw std::invalid_argument("training option " + what);
  };
  require(batch_size >= 1, "batch_size must be >= 1");
  require(epochs >= 0 || epochs == kEpochsAuto, "epochs must be >= 0 (or kEpochsAuto)");
  require(patience_epochs >= 0, "patience_epochs must be >= 0");
  require(learning_rate > 0 && std::isfinite(learning_rate), "learning_rate must be positive");
  require(warmup_fraction >= 0 && warmup_fraction < 1, "warmup_fraction must be in [0, 1)");
  require(final_lr_fraction >= 0 && final_lr_fraction <= 1, "final_lr_fraction must be in [0, 1]");
  require(weight_decay >= 0, "weight_decay must be >= 0");
  require(class_loss_weight >= 0, "class_loss_weight must be >= 0");
  require(max_minutes >= 0, "max_minutes must be >= 0");
  require(checkpoint_interval_s > 0, "checkpoint_interval_s must be positive");
  require(progress_interval_s >= 0, "progress_interval_s must be >= 0");
  require(aten_threads >= 1 && blas_threads >= 1, "aten_threads and blas_threads must be >= 1");
  if (!centroid_weighting.empty()) {
    try {
      parseCentroidWeighting(centroid_weighting);
    } catch (const std::invalid_argument& e) {
      require(false, std::string("centroid_weighting: ") + e.what());
    }
  }
  require(std::isfinite(value_saturation), "value_saturation must be finite");
  require(feature_corrections.empty() || feature_corrections == "on" || feature_corrections == "off",
          "feature_corrections must be 'on' or 'off', not '" + feature_corrections + "'");
  require(spot_readout.empty() || spot_readout == "centroid" || spot_readout == "symmetry",
          "spot_readout must be 'centroid' or 'symmetry', not '" + spot_readout + "'");
  require(lattice_phase.empty() || lattice_phase == "spotwise" || lattice_phase == "whole_spots",
          "lattice_phase must be 'spotwise' or 'whole_spots', not '" + lattice_phase + "'");
  if (!head.empty()) {
    try {
      validateHeadChoice(head);
    } catch (const std::invalid_argument& e) {
      require(false, e.what());
    }
  }
  const auto& a = augmentation;
  for (double p : {a.gain_probability, a.noise_probability, a.threshold_probability, a.dropout_probability})
    require(p >= 0 && p <= 1, "augmentation probabilities must be in [0, 1]");
  require(a.gain_sigma >= 0 && a.noise_sigma_dn >= 0 && a.dropout_max_radius_px >= 0,
          "augmentation magnitudes must be >= 0");
  require(a.threshold_max_fraction >= 0 && a.threshold_max_fraction < 1,
          "augmentation threshold_max_fraction must be in [0, 1)");
}

FreshModelDesign freshModelDesign(const SensorConfig& sensor, TrainOptions& options) {
  if (options.arch.empty()) options.arch = defaultArchName();
  FreshModelDesign d;
  d.arch = archPreset(options.arch, sensor.numSubFovClasses());
  if (options.feature_corrections.empty()) options.feature_corrections = "on";
  d.arch.feature_corrections = options.feature_corrections == "on";
  if (options.lattice_phase.empty()) options.lattice_phase = "spotwise";
  d.head.lattice_spotwise_phase = options.lattice_phase == "spotwise";
  if (options.head.empty()) options.head = "auto";
  d.head.head = options.head;
  // Site weights: the geometric head reads each spot's intensity-weighted
  // centroid (the baseline's; its search anchors on the brightest site). A
  // learned factor on them read drawn mask G 9 % worse than the baseline, the
  // plain intensity level with it (docs/sscnn.md#site-weights-and-value-saturation). The other
  // heads start from equal weights and learn them.
  const bool geometric_head = metadataFor(sensor, d.arch, d.head).arch.geometric_head;
  if (options.centroid_weighting.empty()) options.centroid_weighting = geometric_head ? "intensity" : "learned";
  d.arch.centroid_weighting = parseCentroidWeighting(options.centroid_weighting);
  // Not given: the geometric head's is chosen on the validation images when
  // the model is written (train/value_saturation_choice), trained with 0.
  d.choose_value_saturation = geometric_head && options.value_saturation < 0.0;
  if (options.value_saturation < 0.0) options.value_saturation = 0.0;
  d.arch.value_saturation = options.value_saturation;
  if (options.spot_readout.empty()) options.spot_readout = "centroid";
  if (options.spot_readout == "symmetry" && !geometric_head)
    throw std::invalid_argument("spot_readout symmetry: only the geometric head reads spots one by one (sensor '" +
                                sensor.name + "' gets the " + headName(metadataFor(sensor, d.arch, d.head).arch) +
                                " head)");
  d.arch.geometric_symmetric_spots = options.spot_readout == "symmetry";
  return d;
}

Trainer::Impl::Impl(const SensorConfig& s, TrainingSet t, TrainingSet v, TrainOptions o)
    : sensor(s), train(std::move(t)), validation(std::move(v)), options(std::move(o)) {
  options.validate();
  if (train.size() == 0) throw std::invalid_argument("no training samples");
  sparse::configureThreads(options.aten_threads, options.blas_threads);
  if (!options.init_model.empty()) {
    model = loadModel(options.init_model, &sensor);  // ModelError names the file and the mismatch
    // Its angle correction fitted that network's bias, which training changes.
    model.meta.angle_correction = AngleCorrection{};
    // Validation reads single images, as training does; calibrate-sigma
    // sets the symmetry again where wanted.
    model.meta.inference_symmetry = InferenceSymmetry::kNone;
    if (options.arch.empty()) options.arch = model.meta.arch.name;
    if (model.meta.arch.name != options.arch)
      throw std::invalid_argument("training option init_model: " + options.init_model + " is " + model.meta.arch.name +
                                  ", not " + options.arch);
    const std::string weighting = centroidWeightingName(model.meta.arch.centroid_weighting);
    if (options.centroid_weighting.empty()) options.centroid_weighting = weighting;
    if (options.centroid_weighting != weighting)
      throw std::invalid_argument("training option init_model: " + options.init_model + " has centroid weighting " +
                                  weighting + ", not " + options.centroid_weighting);
    if (options.value_saturation < 0.0) options.value_saturation = model.meta.arch.value_saturation;
    if (options.value_saturation != model.meta.arch.value_saturation)
      throw std::invalid_argument("training option init_model: " + options.init_model + " has value saturation " +
                                  std::to_string(model.meta.arch.value_saturation) + ", not " +
                                  std::to_string(options.value_saturation));
    const std::string corrections = model.meta.arch.feature_corrections ? "on" : "off";
    if (options.feature_corrections.empty()) options.feature_corrections = corrections;
    if (options.feature_corrections != corrections)
      throw std::invalid_argument("training option init_model: " + options.init_model + " has feature corrections " +
                                  corrections + ", not " + options.feature_corrections);
    const std::string readout = model.meta.arch.geometric_symmetric_spots ? "symmetry" : "centroid";
    if (options.spot_readout.empty()) options.spot_readout = readout;
    if (options.spot_readout != readout)
      throw std::invalid_argument("training option init_model: " + options.init_model + " reads spots by " + readout +
                                  ", not " + options.spot_readout);
    const std::string phase = model.meta.arch.lattice_spotwise_phase ? "spotwise" : "whole_spots";
    if (options.lattice_phase.empty()) options.lattice_phase = phase;
    if (model.meta.arch.latticeHead() && options.lattice_phase != phase)
      throw std::invalid_argument("training option init_model: " + options.init_model + " has lattice phase " + phase +
                                  ", not " + options.lattice_phase);
    const std::string head = headName(model.meta.arch);
    if (options.head.empty() || options.head == "auto") options.head = head;
    if (options.head != head)
      throw std::invalid_argument("training option init_model: " + options.init_model + " has the " + head +
                                  " head, not the " + options.head);
  } else {
    const FreshModelDesign design = freshModelDesign(sensor, options);
    model = createModel(sensor, design.arch, deriveSeed(options.seed, 0xA7C4), design.head);
    choose_value_saturation = design.choose_value_saturation;
  }
  if (options.epochs == kEpochsAuto)
    options.epochs = model.meta.arch.pattern_head     ? kPatternHeadEpochs
                     : model.meta.arch.geometric_head ? kGeometricHeadEpochs
                                                      : kClassicHeadEpochs;
  if (model.meta.arch.pattern_head && options.epochs > 0)
    throw std::invalid_argument(
        "the pattern head has nothing to train by gradient (its angles come from the whole-pattern solve): use "
        "--epochs 0 or auto, then dss calibrate-sigma for its angle correction and sigma");
  model.net->train();
  optimizer = std::make_unique<torch::optim::AdamW>(
      model.net->parameters(), torch::optim::AdamWOptions(options.learning_rate).weight_decay(options.weight_decay));
  data_fingerprint = trainingDataFingerprint(train) ^ splitmix64(trainingDataFingerprint(validation));
}

// The current weights with training summary and metrics in the metadata.
Model Trainer::Impl::withMetadata(const std::string& data_description) const {
  Model m = model;
  YAML::Emitter t;
  t << YAML::BeginMap;
  if (!data_description.empty()) t << YAML::Key << "data" << YAML::Value << data_description;
  t << YAML::Key << "train_samples" << YAML::Value << train.size();
  t << YAML::Key << "validation_samples" << YAML::Value << validation.size();
  // `epoch` counts the epochs done, also in a run resumed after the last one.
  t << YAML::Key << "epochs_completed" << YAML::Value << epoch;
  t << YAML::Key << "epochs_scheduled" << YAML::Value << options.epochs;
  t << YAML::Key << "batch_size" << YAML::Value << options.batch_size;
  t << YAML::Key << "optimizer" << YAML::Value << "AdamW, linear warm-up + cosine decay";
  t << YAML::Key << "learning_rate" << YAML::Value << options.learning_rate;
  t << YAML::Key << "seed" << YAML::Value << options.seed;
  if (!options.init_model.empty()) t << YAML::Key << "init_model" << YAML::Value << options.init_model;
  t << YAML::Key << "wall_s" << YAML::Value << last.elapsed_s;
  t << YAML::EndMap;
  m.meta.training_yaml = t.c_str();
  m.meta.metrics_yaml = validationYaml(last);
  return m;
}

Trainer::Trainer(const SensorConfig& sensor, TrainingSet train, TrainingSet validation, TrainOptions options)
    : impl_(std::make_unique<Impl>(sensor, std::move(train), std::move(validation), std::move(options))) {}

Trainer::~Trainer() = default;

void Trainer::resume(const std::string& checkpoint_path) { impl_->resume(checkpoint_path); }
std::int64_t Trainer::stepsPerEpoch() const { return impl_->stepsPerEpoch(); }

const std::string& Trainer::archName() const { return impl_->options.arch; }

TrainProgress Trainer::measureValidation() {
  TrainProgress p;
  impl_->measure(p);
  return p;
}

std::vector<float> Trainer::flatWeights() const {
  std::vector<float> flat;
  for (const auto& p : impl_->model.net->parameters()) {
    const auto c = p.detach().to(torch::kFloat).contiguous();
    flat.insert(flat.end(), c.data_ptr<float>(), c.data_ptr<float>() + c.numel());
  }
  return flat;
}

TrainResult Trainer::run(const std::function<void(const TrainProgress&)>& on_progress, const std::atomic<bool>& stop) {
  Impl& m = *impl_;
  const auto start = Clock::now();
  auto last_checkpoint = start, last_report = start;
  const std::int64_t steps_per_epoch = m.stepsPerEpoch();
  const std::int64_t total_steps = steps_per_epoch * m.options.epochs;
  std::int64_t steps_this_run = 0;
  double loss_sum = 0;
  int loss_count = 0;
  TrainResult result;
  m.last.epochs = m.options.epochs;
  m.last.steps_per_epoch = steps_per_epoch;

  auto report = [&](bool epoch_end) {
    const double run_s = secondsSince(start);
    m.last.epoch = m.epoch;
    m.last.step_in_epoch = m.step_in_epoch;
    m.last.epoch_end = epoch_end;
    m.last.loss = loss_count ? loss_sum / loss_count : m.last.loss;
    m.last.elapsed_s = m.elapsed_before_s + run_s;
    m.last.images_per_s = run_s > 0 ? static_cast<double>(steps_this_run * m.imagesPerStep()) / run_s : 0.0;
    const std::int64_t done = static_cast<std::int64_t>(m.epoch) * steps_per_epoch + m.step_in_epoch;
    m.last.eta_s = steps_this_run > 0
                       ? run_s / static_cast<double>(steps_this_run) * static_cast<double>(total_steps - done)
                       : 0.0;
    loss_sum = 0;
    loss_count = 0;
    if (on_progress) on_progress(m.last);
    last_report = Clock::now();
  };
  auto checkpoint = [&] {
    if (m.options.checkpoint_path.empty()) return;
    m.saveCheckpoint(m.options.checkpoint_path, m.elapsed_before_s + secondsSince(start));
    last_checkpoint = Clock::now();
  };

  if (m.options.epochs == 0 && m.best_model_bytes.empty()) {
    // The model as created (a geometric head's design, the physics prior):
    // validated once, so that it is saved with its sigma and input envelope.
    m.last.epoch = 0;
    m.validate();
    m.best_epoch = m.last.best_epoch = -1;
    report(false);
  }
  int epochs_without_improvement = m.best_epoch < 0 ? 0 : m.epoch - 1 - m.best_epoch;
  while (m.epoch < m.options.epochs) {
    const auto order = m.epochOrder(m.epoch);
    while (m.step_in_epoch < steps_per_epoch) {
      if (stop) {
        result.stop = TrainStop::interrupted;
        break;
      }
      if (m.options.max_minutes > 0 && m.elapsed_before_s + secondsSince(start) > 60.0 * m.options.max_minutes) {
        result.stop = TrainStop::time_limit;
        break;
      }
      loss_sum += m.step(order);
      ++loss_count;
      ++m.step_in_epoch;
      ++steps_this_run;
      if (secondsSince(last_report) >= m.options.progress_interval_s) report(false);
      if (secondsSince(last_checkpoint) >= m.options.checkpoint_interval_s) checkpoint();
    }
    if (result.stop != TrainStop::finished) break;
    m.last.epoch = m.epoch;
    m.validate();
    const bool improved = m.best_epoch == m.epoch;
    epochs_without_improvement = improved ? 0 : epochs_without_improvement + 1;
    report(true);
    ++m.epoch;
    m.step_in_epoch = 0;
    if (m.options.patience_epochs > 0 && epochs_without_improvement >= m.options.patience_epochs &&
        m.epoch < m.options.epochs) {
      result.stop = TrainStop::early_stopped;
      break;
    }
  }
  checkpoint();
  m.last.elapsed_s = m.elapsed_before_s + secondsSince(start);
  result.last = m.last;
  result.epochs_completed = m.epoch;
  result.wall_s = m.last.elapsed_s;
  return result;
}

std::string Trainer::saveModel(const std::string& path, const std::string& data_description) const {
  const Impl& m = *impl_;
  std::string finish;
  Model out = m.withMetadata(data_description);
  if (!m.best_model_bytes.empty()) {
    // The best validated weights, with the summary of the whole run.
    // Its metrics are those of its own validation.
    Model best = deserializeModel(m.best_model_bytes, "best weights", &m.sensor);
    best.meta.training_yaml = out.meta.training_yaml;
    YAML::Node metrics = YAML::Load(best.meta.metrics_yaml);
    metrics["best_epoch"] = m.best_epoch;
    best.meta.metrics_yaml = YAML::Dump(metrics);
    if (m.choose_value_saturation) {
      // With its angle correction refitted on the held-out images, which the
      // network's own smooth correction may have left short of its least squares.
      const ValueSaturationChoice c =
          chooseValueSaturation(best, m.validation, m.options.validation_max, kHeldOutCorrectionMaxDegree);
      finish = "value saturation " + formatNumber(c.chosen) + " chosen, angle correction of degree " +
               std::to_string(c.correction.degree) + "; held-out RMS per candidate:";
      for (std::size_t k = 0; k < c.candidates.size(); ++k)
        finish += " " + formatNumber(c.candidates[k]) + ": " + formatNumber(c.cross_validated_rms_deg[k]) + " deg";
    }
    // The level of the predicted sigma, fitted on the held-out images (on
    // this copy: the live network keeps training if the run goes on).
    calibrateSigma(best, m.validation, m.options.validation_max);
    recordInputEnvelope(best.meta, measureInputEnvelope(m.train.siteCounts(best.meta.input.max_sites)));
    out = best;
  }
  ::dss::saveModel(out, path);
  return finish;
}

}  // namespace dss
