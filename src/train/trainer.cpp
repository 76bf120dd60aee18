#include "digital_sun_sensor/train/trainer.h"

#include <torch/optim/adamw.h>
#include <torch/serialize/input-archive.h>
#include <torch/serialize/output-archive.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <numeric>
#include <sstream>

#include "digital_sun_sensor/common/container.h"
#include "digital_sun_sensor/common/file_io.h"
#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/model/input_envelope.h"
#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/model/sparse_input.h"
#include "digital_sun_sensor/sparse/threads.h"
#include "digital_sun_sensor/train/loss.h"
#include "digital_sun_sensor/train/sigma_calibration.h"
#include "digital_sun_sensor/train/validation_error.h"

namespace dss {
namespace {

using Clock = std::chrono::steady_clock;
// Checkpoints are the package's container (common/container): state YAML,
// current model file, best model file, optimizer state. (Checkpoints of the
// earlier "DSSCKPT1" framing are refused by name: they were made by an older
// build and resume there.)
constexpr char kCheckpointMagic[9] = "DSSCKPNT";
constexpr std::uint32_t kCheckpointVersion = 1;

double secondsSince(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

// Identifies the training data: a resumed run must see exactly the same samples.
std::uint64_t fingerprint(const TrainingSet& set) {
  std::uint64_t h = splitmix64(set.size());
  for (const auto& s : set.samples()) {
    std::uint64_t a, b;
    std::memcpy(&a, &s.alpha_rad, 8);
    std::memcpy(&b, &s.beta_rad, 8);
    h = splitmix64(h ^ a) ^ splitmix64(b + s.pixels.size());
  }
  return h;
}

// Copies every tensor of `to` from the tensor of the same name and shape in
// `from`; a missing or differently shaped one is a CheckpointError.
void copyTensorsByName(const torch::OrderedDict<std::string, torch::Tensor>& from,
                       torch::OrderedDict<std::string, torch::Tensor> to, const std::string& origin) {
  for (auto& item : to) {
    const torch::Tensor* source = from.find(item.key());
    if (!source) throw CheckpointError(origin + ": the checkpoint's model lacks tensor '" + item.key() + "'");
    if (source->sizes() != item.value().sizes())
      throw CheckpointError(origin + ": tensor '" + item.key() + "' has another shape in the checkpoint");
    item.value().copy_(*source);
  }
}

std::vector<std::string> unpackCheckpoint(const std::string& bytes, const std::string& origin) {
  if (bytes.rfind("DSSCKPT1", 0) == 0)
    throw CheckpointError(origin +
                          ": a checkpoint of an older format (DSSCKPT1): resume it with the build that wrote "
                          "it, or start the training afresh");
  Container file;
  try {
    file = unpackContainer(bytes, kCheckpointMagic, "training checkpoint", origin);
  } catch (const ContainerError& e) {
    throw CheckpointError(e.what());
  }
  if (file.version != kCheckpointVersion || file.sections.size() != 4)
    throw CheckpointError(origin + ": checkpoint format version " + std::to_string(file.version) + " with " +
                          std::to_string(file.sections.size()) + " sections (this build reads version " +
                          std::to_string(kCheckpointVersion) + ", 4 sections)");
  return file.sections;
}

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
  require(epochs >= 1, "epochs must be >= 1");
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
  require(feature_corrections.empty() || feature_corrections == "on" || feature_corrections == "off",
          "feature_corrections must be 'on' or 'off', not '" + feature_corrections + "'");
  require(lattice_phase.empty() || lattice_phase == "spotwise" || lattice_phase == "whole_spots",
          "lattice_phase must be 'spotwise' or 'whole_spots', not '" + lattice_phase + "'");
  const auto& a = augmentation;
  for (double p : {a.gain_probability, a.noise_probability, a.threshold_probability, a.dropout_probability})
    require(p >= 0 && p <= 1, "augmentation probabilities must be in [0, 1]");
  require(a.gain_sigma >= 0 && a.noise_sigma_dn >= 0 && a.dropout_max_radius_px >= 0,
          "augmentation magnitudes must be >= 0");
  require(a.threshold_max_fraction >= 0 && a.threshold_max_fraction < 1,
          "augmentation threshold_max_fraction must be in [0, 1)");
}

struct Trainer::Impl {
  SensorConfig sensor;
  TrainingSet train, validation;
  TrainOptions options;
  Model model;
  std::unique_ptr<torch::optim::AdamW> optimizer;
  std::uint64_t data_fingerprint = 0;

  // Position and history: everything a resumed run needs besides weights.
  int epoch = 0;
  std::int64_t step_in_epoch = 0;
  double elapsed_before_s = 0.0;  // wall time of earlier runs
  double best_val_mean_deg = 0.0;
  int best_epoch = -1;
  std::string best_model_bytes;  // serialized best model ("" until validated)
  TrainProgress last;

  Impl(const SensorConfig& s, TrainingSet t, TrainingSet v, TrainOptions o)
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
        throw std::invalid_argument("training option init_model: " + options.init_model + " is " +
                                    model.meta.arch.name + ", not " + options.arch);
      const std::string weighting = centroidWeightingName(model.meta.arch.centroid_weighting);
      if (options.centroid_weighting.empty()) options.centroid_weighting = weighting;
      if (options.centroid_weighting != weighting)
        throw std::invalid_argument("training option init_model: " + options.init_model + " has centroid weighting " +
                                    weighting + ", not " + options.centroid_weighting);
      const std::string corrections = model.meta.arch.feature_corrections ? "on" : "off";
      if (options.feature_corrections.empty()) options.feature_corrections = corrections;
      if (options.feature_corrections != corrections)
        throw std::invalid_argument("training option init_model: " + options.init_model + " has feature corrections " +
                                    corrections + ", not " + options.feature_corrections);
      const std::string phase = model.meta.arch.lattice_spotwise_phase ? "spotwise" : "whole_spots";
      if (options.lattice_phase.empty()) options.lattice_phase = phase;
      if (model.meta.arch.latticeHead() && options.lattice_phase != phase)
        throw std::invalid_argument("training option init_model: " + options.init_model + " has lattice phase " +
                                    phase + ", not " + options.lattice_phase);
    } else {
      if (options.arch.empty()) options.arch = defaultArchName();
      if (options.centroid_weighting.empty()) options.centroid_weighting = "learned";
      ArchSpec arch = archPreset(options.arch, sensor.numSubFovClasses());
      arch.centroid_weighting = parseCentroidWeighting(options.centroid_weighting);
      if (options.feature_corrections.empty()) options.feature_corrections = "on";
      arch.feature_corrections = options.feature_corrections == "on";
      if (options.lattice_phase.empty()) options.lattice_phase = "spotwise";
      HeadOptions head;
      head.lattice_spotwise_phase = options.lattice_phase == "spotwise";
      model = createModel(sensor, arch, deriveSeed(options.seed, 0xA7C4), head);
    }
    model.net->train();
    optimizer = std::make_unique<torch::optim::AdamW>(
        model.net->parameters(), torch::optim::AdamWOptions(options.learning_rate).weight_decay(options.weight_decay));
    data_fingerprint = fingerprint(train) ^ splitmix64(fingerprint(validation));
  }

  std::int64_t imagesPerStep() const {
    return std::min<std::int64_t>(options.batch_size, static_cast<std::int64_t>(train.size()));
  }

  std::int64_t stepsPerEpoch() const {
    return std::max<std::int64_t>(1, static_cast<std::int64_t>(train.size()) / options.batch_size);
  }

  double learningRate(std::int64_t global_step) const {
    const double total = static_cast<double>(stepsPerEpoch()) * options.epochs;
    const double warmup = std::max(1.0, options.warmup_fraction * total);
    const double s = static_cast<double>(global_step);
    if (s < warmup) return options.learning_rate * (s + 1) / warmup;
    const double t = std::min(1.0, (s - warmup) / std::max(1.0, total - warmup));
    const double floor = options.final_lr_fraction;
    return options.learning_rate * (floor + (1 - floor) * 0.5 * (1 + std::cos(3.14159265358979323846 * t)));
  }

  // The epoch's data order: a seeded permutation, so a resumed run sees the same.
  std::vector<std::size_t> epochOrder(int e) const {
    std::vector<std::size_t> order(train.size());
    std::iota(order.begin(), order.end(), 0);
    Rng rng(deriveSeed(options.seed, 0xE90C0000ULL + static_cast<std::uint64_t>(e)));
    for (std::size_t i = order.size(); i > 1; --i) std::swap(order[i - 1], order[rng.below(i)]);
    return order;
  }

  // One optimizer step on the batch at (epoch, step); returns the loss.
  double step(const std::vector<std::size_t>& order) {
    const auto b0 = static_cast<std::size_t>(step_in_epoch * options.batch_size);
    std::vector<SparseSample> augmented;
    augmented.reserve(static_cast<std::size_t>(options.batch_size));
    std::vector<float> targets;
    std::vector<std::int64_t> classes;
    // A training set smaller than a batch makes one short batch per epoch.
    const std::size_t b1 = std::min(order.size(), b0 + static_cast<std::size_t>(options.batch_size));
    for (std::size_t k = b0; k < b1; ++k) {
      const SparseSample& s = train.samples()[order[k]];
      augmented.push_back(augment(s, train.spec(), options.augmentation,
                                  deriveSeed(options.seed, (static_cast<std::uint64_t>(epoch) << 32) + k)));
      targets.push_back(static_cast<float>(s.alpha_rad / model.meta.angle_scale_rad));
      targets.push_back(static_cast<float>(s.beta_rad / model.meta.angle_scale_rad));
      classes.push_back(std::max(0, s.subfov_class));
    }
    std::vector<const SparseSample*> batch;
    for (const auto& s : augmented) batch.push_back(&s);
    const auto input = encodeSamples(batch, train.spec());
    const auto target = torch::tensor(targets).view({-1, 2});

    const double lr = learningRate(epoch * stepsPerEpoch() + step_in_epoch);
    for (auto& group : optimizer->param_groups()) static_cast<torch::optim::AdamWOptions&>(group.options()).lr(lr);
    last.learning_rate = lr;
    optimizer->zero_grad();
    // The true classes resolve a class-resolved lattice while training, so the
    // angles learn from the right pitch before the classifier has learned.
    const auto class_tensor = torch::tensor(classes);
    const auto out = model.net->forward(input, class_tensor);
    const double class_weight = sensor.numSubFovClasses() > 1 ? options.class_loss_weight : 0.0;
    const auto loss = trainingLoss(out, target, class_tensor, model.meta.arch.residual_scale, class_weight);
    loss.backward();
    optimizer->step();
    return loss.item<double>();
  }

  // Fills the val_* fields of `out` from (at most validation_max) validation samples.
  void measure(TrainProgress& out) {
    if (validation.size() == 0) return;
    model.net->eval();
    torch::NoGradGuard no_grad;
    const std::size_t n = std::min(validation.size(), options.validation_max);
    const double stride = static_cast<double>(validation.size()) / static_cast<double>(n);
    std::vector<const SparseSample*> picked;
    for (std::size_t i = 0; i < n; ++i)
      picked.push_back(&validation.samples()[static_cast<std::size_t>(static_cast<double>(i) * stride)]);
    const ValidationError v = summarizeValidation(picked, model.predictSamples(picked));
    model.net->train();
    out.val_alpha_mean_deg = v.alpha_mean_deg;
    out.val_beta_mean_deg = v.beta_mean_deg;
    out.val_alpha_max_deg = v.alpha_max_deg;
    out.val_beta_max_deg = v.beta_max_deg;
    out.val_class_accuracy = v.class_accuracy;
    out.val_gross = static_cast<std::int64_t>(v.gross);
  }

  void validate() {
    last.epoch_end = true;
    if (validation.size() == 0) return;
    measure(last);
    const double mean = 0.5 * (last.val_alpha_mean_deg + last.val_beta_mean_deg);
    if (best_epoch < 0 || mean < best_val_mean_deg) {
      best_val_mean_deg = mean;
      best_epoch = last.epoch;
      best_model_bytes = serializeModel(withMetadata(""));
    }
    last.best_val_mean_deg = best_val_mean_deg;
    last.best_epoch = best_epoch;
  }

  // `elapsed_s`: training wall time up to now, over every run of this job.
  std::string stateYaml(double elapsed_s) const {
    YAML::Emitter e;
    e << YAML::BeginMap;
    e << YAML::Key << "sensor" << YAML::Value << sensor.name;
    e << YAML::Key << "arch" << YAML::Value << options.arch;
    e << YAML::Key << "centroid_weighting" << YAML::Value << options.centroid_weighting;
    e << YAML::Key << "feature_corrections" << YAML::Value << options.feature_corrections;
    e << YAML::Key << "lattice_phase" << YAML::Value << options.lattice_phase;
    e << YAML::Key << "batch_size" << YAML::Value << options.batch_size;
    e << YAML::Key << "epochs" << YAML::Value << options.epochs;
    e << YAML::Key << "seed" << YAML::Value << options.seed;
    e << YAML::Key << "data_fingerprint" << YAML::Value << data_fingerprint;
    e << YAML::Key << "epoch" << YAML::Value << epoch;
    e << YAML::Key << "step_in_epoch" << YAML::Value << step_in_epoch;
    e << YAML::Key << "elapsed_s" << YAML::Value << elapsed_s;
    e << YAML::Key << "best_val_mean_deg" << YAML::Value << best_val_mean_deg;
    e << YAML::Key << "best_epoch" << YAML::Value << best_epoch;
    e << YAML::EndMap;
    return e.c_str();
  }

  std::string optimizerBytes() const {
    torch::serialize::OutputArchive archive;
    optimizer->save(archive);
    std::ostringstream stream;
    archive.save_to(stream);
    return stream.str();
  }

  void saveCheckpoint(const std::string& path, double elapsed_s) const {
    writeFileAtomic(path,
                    packContainer(kCheckpointMagic, kCheckpointVersion,
                                  {stateYaml(elapsed_s), serializeModel(model), best_model_bytes, optimizerBytes()}));
  }

  void resume(const std::string& path) {
    std::string bytes;
    try {
      bytes = readFile(path);
    } catch (const std::runtime_error& e) {
      throw CheckpointError(std::string("checkpoint: ") + e.what());
    }
    const std::string origin = "checkpoint '" + path + "'";
    const auto sections = unpackCheckpoint(bytes, origin);
    YAML::Node state;
    try {
      state = YAML::Load(sections[0]);
      auto expect = [&](const char* key, const std::string& want) {
        const std::string have = state[key].as<std::string>();
        if (have != want)
          throw CheckpointError(origin + ": made with " + key + " '" + have + "', this run has '" + want + "'");
      };
      expect("sensor", sensor.name);
      expect("arch", options.arch);
      if (state["centroid_weighting"])  // absent in checkpoints made before it existed
        expect("centroid_weighting", options.centroid_weighting);
      if (state["feature_corrections"])  // absent in checkpoints made before it existed
        expect("feature_corrections", options.feature_corrections);
      if (state["lattice_phase"])  // absent in checkpoints made before it existed
        expect("lattice_phase", options.lattice_phase);
      expect("batch_size", std::to_string(options.batch_size));
      expect("epochs", std::to_string(options.epochs));
      expect("seed", std::to_string(options.seed));
      if (state["data_fingerprint"].as<std::uint64_t>() != data_fingerprint)
        throw CheckpointError(origin + ": made from different training data (bags, split or image count differ)");
      epoch = state["epoch"].as<int>();
      step_in_epoch = state["step_in_epoch"].as<std::int64_t>();
      elapsed_before_s = state["elapsed_s"].as<double>();
      best_val_mean_deg = state["best_val_mean_deg"].as<double>();
      best_epoch = state["best_epoch"].as<int>();
    } catch (const YAML::Exception& e) {
      throw CheckpointError(origin + ": unreadable state: " + e.what());
    }
    try {
      Model restored = deserializeModel(sections[1], origin, &sensor);
      torch::NoGradGuard no_grad;
      // By name and shape, as a model file is read.
      copyTensorsByName(restored.net->named_parameters(), model.net->named_parameters(), origin);
      copyTensorsByName(restored.net->named_buffers(), model.net->named_buffers(), origin);
      best_model_bytes = sections[2];
      torch::serialize::InputArchive archive;
      std::istringstream stream(sections[3]);
      archive.load_from(stream);
      optimizer->load(archive);
    } catch (const ModelError& e) {
      throw CheckpointError(e.what());
    } catch (const c10::Error& e) {
      throw CheckpointError(origin + ": optimizer state unreadable: " + e.what_without_backtrace());
    }
    model.net->train();
  }

  // The current weights with training summary and metrics in the metadata.
  Model withMetadata(const std::string& data_description) const {
    Model m = model;
    YAML::Emitter t;
    t << YAML::BeginMap;
    if (!data_description.empty()) t << YAML::Key << "data" << YAML::Value << data_description;
    t << YAML::Key << "train_samples" << YAML::Value << train.size();
    t << YAML::Key << "validation_samples" << YAML::Value << validation.size();
    t << YAML::Key << "epochs_completed" << YAML::Value << last.epoch + (last.epoch_end ? 1 : 0);
    t << YAML::Key << "epochs_scheduled" << YAML::Value << options.epochs;
    t << YAML::Key << "batch_size" << YAML::Value << options.batch_size;
    t << YAML::Key << "optimizer" << YAML::Value << "AdamW, linear warm-up + cosine decay";
    t << YAML::Key << "learning_rate" << YAML::Value << options.learning_rate;
    t << YAML::Key << "seed" << YAML::Value << options.seed;
    if (!options.init_model.empty()) t << YAML::Key << "init_model" << YAML::Value << options.init_model;
    t << YAML::Key << "wall_s" << YAML::Value << last.elapsed_s;
    t << YAML::EndMap;
    m.meta.training_yaml = t.c_str();
    YAML::Emitter v;
    v << YAML::BeginMap;
    v << YAML::Key << "validation_alpha_mean_deg" << YAML::Value << last.val_alpha_mean_deg;
    v << YAML::Key << "validation_beta_mean_deg" << YAML::Value << last.val_beta_mean_deg;
    v << YAML::Key << "validation_alpha_max_deg" << YAML::Value << last.val_alpha_max_deg;
    v << YAML::Key << "validation_beta_max_deg" << YAML::Value << last.val_beta_max_deg;
    v << YAML::Key << "validation_class_accuracy" << YAML::Value << last.val_class_accuracy;
    v << YAML::Key << "validation_gross" << YAML::Value << last.val_gross;
    v << YAML::EndMap;
    m.meta.metrics_yaml = v.c_str();
    return m;
  }
};

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
  result.wall_s = m.last.elapsed_s;
  return result;
}

void Trainer::saveModel(const std::string& path, const std::string& data_description) const {
  const Impl& m = *impl_;
  Model out = m.withMetadata(data_description);
  if (!m.best_model_bytes.empty()) {
    // The best validated weights, with the summary of the whole run.
    // Its metrics are those of its own validation.
    Model best = deserializeModel(m.best_model_bytes, "best weights", &m.sensor);
    best.meta.training_yaml = out.meta.training_yaml;
    YAML::Node metrics = YAML::Load(best.meta.metrics_yaml);
    metrics["best_epoch"] = m.best_epoch;
    best.meta.metrics_yaml = YAML::Dump(metrics);
    // The level of the predicted sigma, fitted on the held-out images (on
    // this copy: the live network keeps training if the run goes on).
    calibrateSigma(best, m.validation, m.options.validation_max);
    recordInputEnvelope(best.meta, measureInputEnvelope(m.train.siteCounts()));
    out = best;
  }
  ::dss::saveModel(out, path);
}

}  // namespace dss
