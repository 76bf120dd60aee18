// Training core: a tiny model learns from a tiny simulated set; an interrupted
// and resumed run reaches the same weights as an uninterrupted one; bad
// checkpoints and options are rejected; augmentation is seeded; the post-hoc
// angle correction removes a smooth bias on held-out images; the geometric
// head's value saturation is chosen on them; the sigma calibration of a
// mirror-averaged model covers as it reports.
#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include <cmath>
#include <cstdio>
#include <fstream>

#include "digital_sun_sensor/common/file_io.h"
#include "digital_sun_sensor/common/limits.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/eval/uncertainty.h"
#include "digital_sun_sensor/model/input_envelope.h"
#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/sim/dataset_generator.h"
#include "digital_sun_sensor/sim/random_mask.h"
#include "digital_sun_sensor/train/bias_calibration.h"
#include "digital_sun_sensor/train/loss.h"
#include "digital_sun_sensor/train/sigma_calibration.h"
#include "digital_sun_sensor/train/trainer.h"
#include "digital_sun_sensor/train/validation_error.h"
#include "digital_sun_sensor/train/value_saturation_choice.h"

namespace dss {
namespace {

SensorConfig tinySensor() {
  // Coarse PSF nodes: rendering speed matters more here than the last 0.01 px.
  return loadSensorConfig(std::string(DSS_SOURCE_DIR) + "/config/sensors/thesis_sa.yaml",
                          {"optics.psf_node_step_deg=3"});
}

TrainingSet simulate(const SensorConfig& sensor, std::uint64_t count, std::uint64_t seed) {
  TrainingSet set(inputSpecFor(sensor));
  DatasetSpec spec;
  spec.count = count;
  spec.seed = seed;
  DatasetGenerator(sensor, spec).run([&](const DatasetItem& item) {
    set.add(item.image, item.truth.alpha_rad, item.truth.beta_rad, item.truth.subfov_class);
  });
  return set;
}

const TrainingSet& tinySet() {
  static const TrainingSet set = simulate(tinySensor(), 480, 17);
  return set;
}

TrainOptions tinyOptions() {
  TrainOptions o;
  o.arch = "resnet10_w16";
  o.batch_size = 16;
  o.epochs = 6;
  o.learning_rate = 3e-3;
  o.seed = 3;
  o.progress_interval_s = 0;               // a callback after every step
  o.augmentation.noise_probability = 0.3;  // exercises the seeded augmentation in resume
  o.augmentation.noise_sigma_dn = 2.0;
  return o;
}

// Three apertures of 60 um drawn with `seed` on thesis_sa's detector, 2.5 mm high.
SensorConfig drawnThreeApertureMask(std::uint64_t seed) {
  RandomMaskOptions mask;
  mask.apertures = 3;
  mask.diameter_um = 60.0;
  mask.min_whole_spots = 1;
  return drawRandomMask(loadSensorConfig(std::string(DSS_SOURCE_DIR) + "/config/sensors/thesis_sa.yaml",
                                         {"optics.psf_node_step_deg=3", "mask.height_mm=2.5"}),
                        mask, seed)
      .config;
}

std::string tempPath(const std::string& name) {
  return (::testing::TempDir().empty() ? "/tmp/" : ::testing::TempDir()) + "dss_train_" + name;
}

TEST(Train, ValidationErrorFallsWellBelowUntrained) {
  TrainingSet train{tinySet().spec()}, validation{tinySet().spec()};
  tinySet().split(0.2, 1, train, validation);
  ASSERT_EQ(validation.size(), 96u);
  Trainer trainer(tinySensor(), train, validation, tinyOptions());
  const TrainProgress untrained = trainer.measureValidation();
  const double untrained_deg = 0.5 * (untrained.val_alpha_mean_deg + untrained.val_beta_mean_deg);
  std::atomic<bool> stop{false};
  int epoch_reports = 0;
  const TrainResult result = trainer.run(
      [&](const TrainProgress& p) {
        epoch_reports += p.epoch_end;
        EXPECT_TRUE(std::isfinite(p.loss));
      },
      stop);
  EXPECT_EQ(result.stop, TrainStop::finished);
  EXPECT_EQ(epoch_reports, 6);
  const double trained_deg = 0.5 * (result.last.val_alpha_mean_deg + result.last.val_beta_mean_deg);
  std::printf("untrained %.4f deg, trained %.4f deg (best %.4f) in %.1f s\n", untrained_deg, trained_deg,
              result.last.best_val_mean_deg, result.wall_s);
  // Untrained, the network is the physics prior: the centre of the active
  // pixels through the nominal pinhole (about 1 px of error here). Learning
  // must do much better than that.
  EXPECT_GT(untrained_deg, 0.005);
  EXPECT_LT(result.last.best_val_mean_deg, 0.5 * untrained_deg);

  // The saved model carries the best weights and the training summary.
  const std::string path = tempPath("model.dssm");
  trainer.saveModel(path, "tiny set");
  const std::string bytes = readFile(path, limits::kMaxModelFileBytes);
  EXPECT_NE(bytes.find("best_epoch"), std::string::npos);
  EXPECT_NE(bytes.find("tiny set"), std::string::npos);
  EXPECT_NE(bytes.find("sigma_mode"), std::string::npos);
  EXPECT_NE(bytes.find("lit_sites_max"), std::string::npos);

  // Its predicted sigma (the head's, rescaled, or a constant) was calibrated on
  // the validation images: 68 % of their errors now lie within 1 sigma (the
  // calibration really reached the network).
  const Model saved = loadModel(path);
  std::vector<const SparseSample*> samples;
  for (const auto& s : validation.samples()) samples.push_back(&s);
  const std::vector<Prediction> predictions = saved.predictSamples(samples);
  std::vector<ErrorAndSigma> za, zb;
  for (std::size_t k = 0; k < samples.size(); ++k) {
    za.push_back({predictions[k].alpha_rad - samples[k]->alpha_rad, std::sqrt(predictions[k].alpha_variance_rad2)});
    zb.push_back({predictions[k].beta_rad - samples[k]->beta_rad, std::sqrt(predictions[k].beta_variance_rad2)});
  }
  EXPECT_NEAR(measureCoverage(za).within[0], 0.683, 0.03);
  EXPECT_NEAR(measureCoverage(zb).within[0], 0.683, 0.03);
  std::remove(path.c_str());
}

TEST(Train, GeometricHeadOnADrawnMaskEndsBelowItsUntrainedError) {
  // A mask nobody tuned for (three apertures drawn with a fixed seed), on a
  // unit whose mask sits 1 % higher than the design the model starts from:
  // the untrained head solves through the design's geometry, and training
  // must learn what it leaves (about 0.03 deg at the edge of the field).
  const SensorConfig design = drawnThreeApertureMask(1);
  SensorConfig unit = design;
  unit.mask.height_mm = 2.525;
  const TrainingSet all = simulate(unit, 400, 29);
  TrainingSet train{all.spec()}, validation{all.spec()};
  all.split(0.25, 1, train, validation);
  TrainOptions options = tinyOptions();
  options.epochs = 8;
  ASSERT_TRUE(metadataFor(design, archPreset(options.arch, design.numSubFovClasses())).arch.geometric_head);
  Trainer trainer(design, train, validation, options);
  const TrainProgress untrained = trainer.measureValidation();
  const double untrained_deg = 0.5 * (untrained.val_alpha_mean_deg + untrained.val_beta_mean_deg);
  std::atomic<bool> stop{false};
  const TrainResult result = trainer.run([](const TrainProgress&) {}, stop);
  std::printf("geometric head: untrained %.5f deg (%d gross), trained %.5f deg in %.1f s\n", untrained_deg,
              static_cast<int>(untrained.val_gross), result.last.best_val_mean_deg, result.wall_s);
  EXPECT_EQ(untrained.val_gross, 0);
  EXPECT_LT(result.last.best_val_mean_deg, 0.5 * untrained_deg);
}

TEST(Train, ResumedRunReachesTheSameWeights) {
  TrainingSet train{tinySet().spec()}, validation{tinySet().spec()};
  tinySet().split(0.2, 1, train, validation);
  TrainOptions options = tinyOptions();
  options.epochs = 2;
  std::atomic<bool> stop{false};

  Trainer uninterrupted(tinySensor(), train, validation, options);
  ASSERT_EQ(uninterrupted.run({}, stop).stop, TrainStop::finished);

  options.checkpoint_path = tempPath("resume.ckpt");
  {
    Trainer first(tinySensor(), train, validation, options);
    // Interrupt mid-epoch: epoch 2, after its 5th step.
    const TrainResult r = first.run(
        [&](const TrainProgress& p) {
          if (p.epoch == 1 && p.step_in_epoch == 5) stop = true;
        },
        stop);
    ASSERT_EQ(r.stop, TrainStop::interrupted);
    EXPECT_NE(first.flatWeights(), uninterrupted.flatWeights());
  }
  stop = false;
  Trainer resumed(tinySensor(), train, validation, options);
  resumed.resume(options.checkpoint_path);
  ASSERT_EQ(resumed.run({}, stop).stop, TrainStop::finished);
  const auto a = uninterrupted.flatWeights(), b = resumed.flatWeights();
  ASSERT_EQ(a.size(), b.size());
  double max_diff = 0;
  for (std::size_t i = 0; i < a.size(); ++i) max_diff = std::max(max_diff, std::abs(double(a[i]) - double(b[i])));
  EXPECT_EQ(max_diff, 0.0) << "weights differ by up to " << max_diff;
  std::remove(options.checkpoint_path.c_str());
}

// Fewer training images than a batch: one short batch per epoch (this used to
// read past the data order).
TEST(Train, TrainingSetSmallerThanABatchTrains) {
  TrainingSet train{tinySet().spec()}, validation{tinySet().spec()};
  for (std::size_t i = 0; i < 6; ++i) train.add(tinySet().samples()[i]);
  for (std::size_t i = 6; i < 10; ++i) validation.add(tinySet().samples()[i]);
  TrainOptions options = tinyOptions();
  options.epochs = 2;
  std::atomic<bool> stop{false};
  Trainer trainer(tinySensor(), train, validation, options);
  const TrainResult result = trainer.run({}, stop);
  EXPECT_EQ(result.stop, TrainStop::finished);
  EXPECT_EQ(result.last.epoch, 1);
  EXPECT_TRUE(std::isfinite(result.last.best_val_mean_deg));
}

// --epochs 0: the model as created (a geometric head's design), validated
// once and saved with its sigma and input envelope, its weights untouched.
// A geometric head left to dss train's defaults reads intensity weights and
// gets the value saturation whose held-out angle correction reads the
// validation images best, with that correction; a given one is kept.
TEST(Train, GeometricHeadChoosesItsValueSaturationOnHeldOutImages) {
  const SensorConfig design = drawnThreeApertureMask(2);
  const TrainingSet all = simulate(design, 200, 31);
  TrainingSet train{all.spec()}, validation{all.spec()};
  all.split(0.5, 1, train, validation);
  TrainOptions options = tinyOptions();
  options.epochs = 0;
  const std::string path = tempPath("saturation.dssmodel");
  std::atomic<bool> stop{false};
  Trainer chooser(design, train, validation, options);
  chooser.run({}, stop);
  const std::string line = chooser.saveModel(path, "test");
  Model chosen = loadModel(path);
  EXPECT_EQ(chosen.meta.arch.centroid_weighting, CentroidWeighting::kIntensity);
  const YAML::Node metrics = YAML::Load(chosen.meta.metrics_yaml);
  ASSERT_TRUE(metrics["value_saturation_cv_rms_deg"]) << chosen.meta.metrics_yaml;
  // The rule, from the recorded scores: least RMS, a later candidate only 1 % better.
  double expected = 0.0, best = 0.0;
  for (const double s : valueSaturationCandidates()) {
    const double rms = metrics["value_saturation_cv_rms_deg"][s].as<double>();
    if (s == 0.0 || rms < 0.99 * best) expected = s, best = rms;
  }
  EXPECT_EQ(chosen.meta.arch.value_saturation, expected);
  EXPECT_EQ(metrics["value_saturation"].as<double>(), expected);
  EXPECT_NE(line.find("value saturation"), std::string::npos) << line;
  std::printf("%s\n", line.c_str());
  // The correction written is the one refitted at the chosen saturation.
  const AngleCorrection written = chosen.meta.angle_correction;
  chooseValueSaturation(chosen, validation, validation.size(), 8, {expected});
  EXPECT_EQ(chosen.meta.angle_correction.degree, written.degree);
  ASSERT_EQ(chosen.meta.angle_correction.alpha.size(), written.alpha.size());
  for (std::size_t k = 0; k < written.alpha.size(); ++k)
    EXPECT_NEAR(chosen.meta.angle_correction.alpha[k], written.alpha[k], 1e-12);

  options.value_saturation = 1.0;
  Trainer given(design, train, validation, options);
  given.run({}, stop);
  EXPECT_EQ(given.saveModel(path, "test"), "");
  const Model kept = loadModel(path);
  std::remove(path.c_str());
  EXPECT_EQ(kept.meta.arch.value_saturation, 1.0);
  EXPECT_FALSE(YAML::Load(kept.meta.metrics_yaml)["value_saturation_cv_rms_deg"]);

  EXPECT_THROW(chooseValueSaturation(chosen, validation, 100, 8, {0.0, -1.0}), std::invalid_argument);
  Model classic = createModel(tinySensor(), "resnet10_w16");
  EXPECT_THROW(chooseValueSaturation(classic, tinySet(), 100, 8), std::invalid_argument);
}

TEST(Train, ZeroEpochsWritesTheModelAsCreated) {
  TrainingSet train{tinySet().spec()}, validation{tinySet().spec()};
  tinySet().split(0.2, 1, train, validation);
  TrainOptions options = tinyOptions();
  options.epochs = 0;
  std::atomic<bool> stop{false};
  Trainer trainer(tinySensor(), train, validation, options);
  const std::vector<float> created = trainer.flatWeights();
  const TrainResult result = trainer.run({}, stop);
  EXPECT_EQ(result.stop, TrainStop::finished);
  EXPECT_EQ(trainer.flatWeights(), created);
  EXPECT_TRUE(std::isfinite(result.last.val_alpha_mean_deg));
  const std::string path = tempPath("as_created.dssmodel");
  trainer.saveModel(path, "test");
  const Model model = loadModel(path);
  std::remove(path.c_str());
  EXPECT_GT(inputEnvelopeOf(model.meta).max_sites, 0);
  EXPECT_NE(model.meta.metrics_yaml.find("validation_alpha_mean_deg"), std::string::npos);
  EXPECT_NE(model.meta.training_yaml.find("epochs_completed: 0"), std::string::npos) << model.meta.training_yaml;
  options.epochs = -2;
  EXPECT_THROW(options.validate(), std::invalid_argument);
}

// epochs "auto" takes the head's schedule: the classic heads' long one, the
// geometric head's two epochs.
TEST(Train, AutoEpochsFollowTheHead) {
  TrainingSet train{tinySet().spec()}, validation{tinySet().spec()};
  tinySet().split(0.2, 1, train, validation);
  TrainOptions options = tinyOptions();
  options.epochs = kEpochsAuto;
  std::atomic<bool> stop{true};
  EXPECT_EQ(Trainer(tinySensor(), train, validation, options).run({}, stop).last.epochs, kClassicHeadEpochs);
  options.head = "geometric";
  EXPECT_EQ(Trainer(tinySensor(), train, validation, options).run({}, stop).last.epochs, kGeometricHeadEpochs);
  options.head = "pattern";  // nothing in its solve trains by gradient
  EXPECT_EQ(Trainer(tinySensor(), train, validation, options).run({}, stop).last.epochs, kPatternHeadEpochs);
  options.epochs = 3;
  EXPECT_THROW(Trainer(tinySensor(), train, validation, options), std::invalid_argument);
}

// --init: training starts from the given model's weights, which must suit
// the sensor and the architecture asked for.
TEST(Train, InitModelGivesTheStartingWeights) {
  TrainingSet train{tinySet().spec()}, validation{tinySet().spec()};
  tinySet().split(0.2, 1, train, validation);
  const std::string init_path = tempPath("init.dssmodel"), out_path = tempPath("from_init.dssmodel");
  saveModel(createModel(tinySensor(), "resnet10_w16", 99), init_path);
  TrainOptions options = tinyOptions();
  options.arch = "";  // taken from the init model
  options.init_model = init_path;
  std::atomic<bool> stop{true};  // no step: the weights stay the init model's
  Trainer trainer(tinySensor(), train, validation, options);
  EXPECT_EQ(trainer.archName(), "resnet10_w16");  // what `dss train` reports
  trainer.run({}, stop);
  trainer.saveModel(out_path, "test");
  const Model init = loadModel(init_path), out = loadModel(out_path);
  std::vector<const SparseSample*> samples;
  for (std::size_t i = 0; i < 4; ++i) samples.push_back(&validation.samples()[i]);
  const auto a = init.predictSamples(samples), b = out.predictSamples(samples);
  for (std::size_t i = 0; i < samples.size(); ++i) EXPECT_EQ(a[i].alpha_rad, b[i].alpha_rad);
  EXPECT_NE(out.meta.training_yaml.find("init_model"), std::string::npos);

  options.arch = "resnet18_w32";
  EXPECT_THROW(Trainer(tinySensor(), train, validation, options), std::invalid_argument);
  options.arch = "";
  options.centroid_weighting = "value";  // the init model's is learned
  try {
    Trainer(tinySensor(), train, validation, options);
    ADD_FAILURE() << "an init model of another centroid weighting was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("has centroid weighting learned, not value"), std::string::npos) << e.what();
  }
  options.centroid_weighting = "";
  options.value_saturation = 1.0;  // the init model's is 0
  try {
    Trainer(tinySensor(), train, validation, options);
    ADD_FAILURE() << "an init model of another value saturation was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("has value saturation"), std::string::npos) << e.what();
  }
  options.value_saturation = -1.0;
  options.init_model = tempPath("missing.dssmodel");
  try {
    Trainer(tinySensor(), train, validation, options);
    ADD_FAILURE() << "a missing init model was accepted";
  } catch (const ModelError& e) {
    EXPECT_NE(std::string(e.what()).find("missing.dssmodel"), std::string::npos) << e.what();
  }
  std::remove(init_path.c_str());
  std::remove(out_path.c_str());
}

TEST(Train, BadCheckpointsAndOptionsAreRejected) {
  TrainingSet train{tinySet().spec()}, validation{tinySet().spec()};
  tinySet().split(0.2, 1, train, validation);
  TrainOptions options = tinyOptions();
  options.epochs = 1;
  options.checkpoint_path = tempPath("bad.ckpt");
  std::atomic<bool> stop{true};  // checkpoint at once
  Trainer(tinySensor(), train, validation, options).run({}, stop);

  auto resumeError = [&](const TrainOptions& o, const TrainingSet& t) -> std::string {
    try {
      Trainer(tinySensor(), t, validation, o).resume(options.checkpoint_path);
    } catch (const CheckpointError& e) {
      return e.what();
    }
    return "";
  };
  TrainOptions other_seed = options;
  other_seed.seed = 4;
  EXPECT_NE(resumeError(other_seed, train).find("seed"), std::string::npos);
  TrainOptions other_weighting = options;
  other_weighting.centroid_weighting = "value";
  EXPECT_NE(resumeError(other_weighting, train).find("centroid_weighting"), std::string::npos);
  TrainOptions other_saturation = options;
  other_saturation.value_saturation = 2.0;
  EXPECT_NE(resumeError(other_saturation, train).find("value_saturation"), std::string::npos);
  TrainOptions other_corrections = options;
  other_corrections.feature_corrections = "off";
  EXPECT_NE(resumeError(other_corrections, train).find("feature_corrections"), std::string::npos);
  TrainOptions other_phase = options;
  other_phase.lattice_phase = "whole_spots";
  EXPECT_NE(resumeError(other_phase, train).find("lattice_phase"), std::string::npos);
  // thesis_sa (one aperture) gets the classic head, which has no spots to read one by one.
  TrainOptions symmetric = options;
  symmetric.spot_readout = "symmetry";
  try {
    Trainer(tinySensor(), train, validation, symmetric);
    ADD_FAILURE() << "a symmetric spot read-out without the geometric head was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("only the geometric head"), std::string::npos) << e.what();
  }
  symmetric.spot_readout = "median";
  EXPECT_THROW(symmetric.validate(), std::invalid_argument);
  TrainingSet fewer{train.spec()};
  for (std::size_t i = 1; i < train.size(); ++i) fewer.add(train.samples()[i]);
  EXPECT_NE(resumeError(options, fewer).find("different training data"), std::string::npos);

  std::string bytes = readFile(options.checkpoint_path, limits::kMaxCheckpointFileBytes);
  bytes[bytes.size() / 2] ^= 0x55;
  writeFileAtomic(options.checkpoint_path, bytes);
  EXPECT_NE(resumeError(options, train).find("checksum"), std::string::npos);
  writeFileAtomic(options.checkpoint_path, "hello");
  EXPECT_NE(resumeError(options, train).find("not a digital_sun_sensor training checkpoint"), std::string::npos);
  writeFileAtomic(options.checkpoint_path, "DSSCKPT1" + std::string(40, 'x'));
  EXPECT_NE(resumeError(options, train).find("older format (DSSCKPT1)"), std::string::npos);
  std::remove(options.checkpoint_path.c_str());
  EXPECT_NE(resumeError(options, train).find("bad.ckpt"), std::string::npos);

  TrainOptions bad = options;
  bad.batch_size = 0;
  EXPECT_THROW(Trainer(tinySensor(), train, validation, bad), std::invalid_argument);
  // The error names the bad value and what is allowed.
  auto rejection = [&](const TrainOptions& o) -> std::string {
    try {
      Trainer(tinySensor(), train, validation, o);
    } catch (const std::invalid_argument& e) {
      return e.what();
    }
    return "accepted";
  };
  bad = options;
  bad.centroid_weighting = "brightest";
  EXPECT_NE(rejection(bad).find("'learned', 'value' or 'intensity', not 'brightest'"), std::string::npos)
      << rejection(bad);
  bad = options;
  bad.feature_corrections = "maybe";
  EXPECT_NE(rejection(bad).find("'on' or 'off', not 'maybe'"), std::string::npos) << rejection(bad);
  AugmentationConfig aug;
  EXPECT_THROW(setAugmentation(aug, "nosie_probability=0.1"), std::invalid_argument);
  EXPECT_THROW(setAugmentation(aug, "noise_probability=x"), std::invalid_argument);
  EXPECT_THROW(setAugmentation(aug, "noise_probability=-1"), std::invalid_argument);
  setAugmentation(aug, "noise_probability=0.5");
  EXPECT_EQ(aug.noise_probability, 0.5);
}

TEST(Train, AugmentationIsSeededAndKeepsLabels) {
  const SparseSample& s = tinySet().samples()[0];
  AugmentationConfig config;
  config.gain_probability = config.noise_probability = config.threshold_probability = config.dropout_probability = 1;
  config.gain_sigma = 0.2;
  config.noise_sigma_dn = 5;
  config.threshold_max_fraction = 0.5;
  config.dropout_max_radius_px = 4;
  const InputSpec& spec = tinySet().spec();
  const SparseSample a = augment(s, spec, config, 9), b = augment(s, spec, config, 9), c = augment(s, spec, config, 10);
  EXPECT_EQ(a.pixels, b.pixels);
  EXPECT_EQ(a.dn, b.dn);
  EXPECT_NE(a.dn, c.dn);
  EXPECT_EQ(a.alpha_rad, s.alpha_rad);
  EXPECT_EQ(a.subfov_class, s.subfov_class);
  EXPECT_FALSE(a.pixels.empty());
  EXPECT_LE(a.pixels.size(), s.pixels.size());
  for (auto v : a.dn) EXPECT_GT(v, spec.threshold_dn);
}

// An image whose lattice was resolved to another aperture than the true one
// (tens of degrees off) adds nothing to the angle terms of the loss, nor any
// gradient to its angles; the class term still sees it.
TEST(Train, WrongApertureImagesAreLeftOutOfTheAngleLoss) {
  SscnnOutput out;
  out.angles = torch::tensor({0.01, -0.02, 0.03, 0.0, 40.0, -60.0}).view({3, 2}).requires_grad_();
  out.log_variance = torch::full({3, 2}, -2.0);
  out.class_logits = torch::zeros({3, 4});
  const auto target = torch::zeros({3, 2});
  const auto classes = torch::tensor({1, 2, 3}, torch::kLong);
  out.resolved_class = torch::tensor({1, 2, 0}, torch::kLong);  // the third resolved wrongly

  SscnnOutput right_two;
  right_two.angles = out.angles.slice(0, 0, 2);
  right_two.log_variance = out.log_variance.slice(0, 0, 2);
  right_two.class_logits = out.class_logits.slice(0, 0, 2);
  const double residual_scale = 0.05;
  const auto loss = trainingLoss(out, target, classes, residual_scale, 0.0);
  EXPECT_NEAR(
      loss.item<double>(),
      trainingLoss(right_two, target.slice(0, 0, 2), classes.slice(0, 0, 2), residual_scale, 0.0).item<double>(), 1e-9);
  loss.backward();
  EXPECT_EQ(out.angles.grad()[2].abs().sum().item<double>(), 0.0);
  EXPECT_GT(out.angles.grad()[0].abs().sum().item<double>(), 0.0);

  // Without a resolved class every image counts: the wrong one dominates.
  SscnnOutput unresolved = out;
  unresolved.resolved_class = torch::Tensor();
  EXPECT_GT(trainingLoss(unresolved, target, classes, residual_scale, 0.0).item<double>(), 1e5);
  // The class term is over every image.
  EXPECT_NEAR(trainingLoss(out, target, classes, residual_scale, 1.0).item<double>() - loss.item<double>(),
              std::log(4.0), 1e-6);
}

// Validation ranks epochs by their accuracy: an image declined by the aperture
// code's check or resolved to a wrong aperture (tens of degrees off) is
// counted, not averaged; a wrong class with a small error (a spot between two
// apertures) and a right class with a large error are averaged.
TEST(Train, ValidationLeavesGrossFailuresOutOfTheMean) {
  std::vector<SparseSample> truth(5);
  std::vector<Prediction> predictions(5);
  const double alpha_error_deg[5] = {0.001, 0.003, 40.0, 50.0, 2.0};
  const int predicted_class[5] = {7, 8, 3, 7, 7};  // truth: class 7
  for (int k = 0; k < 5; ++k) {
    truth[k].alpha_rad = 0.1;
    truth[k].beta_rad = -0.2;
    truth[k].subfov_class = 7;
    predictions[k].alpha_rad = 0.1 + alpha_error_deg[k] * kRadPerDeg;
    predictions[k].beta_rad = -0.2 + 0.002 * kRadPerDeg;
    predictions[k].subfov_class = predicted_class[k];
  }
  predictions[3].code_margin = 1.2;  // declined as the estimator would
  std::vector<const SparseSample*> samples;
  for (const auto& t : truth) samples.push_back(&t);

  const ValidationError v = summarizeValidation(samples, predictions);
  EXPECT_EQ(v.images, 5u);
  EXPECT_EQ(v.gross, 2u);  // the wrong aperture (40 deg) and the declined one
  EXPECT_NEAR(v.alpha_mean_deg, (0.001 + 0.003 + 2.0) / 3.0, 1e-9);
  EXPECT_NEAR(v.alpha_max_deg, 2.0, 1e-9);
  EXPECT_NEAR(v.beta_mean_deg, 0.002, 1e-9);
  EXPECT_NEAR(v.class_accuracy, 3.0 / 5.0, 1e-12);

  // Nothing left to rank by: the worst score, not a perfect one.
  for (auto& p : predictions) p.code_margin = 1.0;
  EXPECT_TRUE(std::isinf(summarizeValidation(samples, predictions).alpha_mean_deg));
  predictions.pop_back();
  EXPECT_THROW(summarizeValidation(samples, predictions), std::invalid_argument);
}

TEST(BiasCalibration, LegendreBasisAndBadCorrectionsInTheModelFile) {
  // By total degree, then by the power of b: 1, P1(a), P1(b), P2(a), P1(a) P1(b), P2(b); P2(x) = (3x^2 - 1) / 2.
  const std::vector<double> expected{1.0, 0.5, -0.25, -0.125, -0.125, -0.40625};
  const auto terms = AngleCorrection::terms(2, 0.5, -0.25);
  ASSERT_EQ(terms.size(), AngleCorrection::termCount(2));
  for (std::size_t k = 0; k < terms.size(); ++k) EXPECT_NEAR(terms[k], expected[k], 1e-15) << k;
  EXPECT_EQ(AngleCorrection::terms(1, 3.0, -7.0), AngleCorrection::terms(1, 1.0, -1.0));  // clamped to the field

  ModelMetadata meta = createModel(tinySensor(), "resnet10_w16").meta;
  meta.angle_correction.degree = 2;
  meta.angle_correction.alpha.assign(6, 1e-3);
  meta.angle_correction.beta.assign(5, 1e-3);
  const std::string yaml = metadataToYaml(meta);
  try {
    metadataFromYaml(yaml, "bad.dssmodel");
    FAIL() << "a correction with a missing coefficient was accepted";
  } catch (const ModelError& e) {
    EXPECT_NE(std::string(e.what()).find("angle_correction"), std::string::npos) << e.what();
  }
}

TEST(BiasCalibration, RemovesASmoothBiasOnHeldOutImages) {
  // Untrained, the network is the physics prior: the centre of the lit pixels
  // through a linear map, whose error grows smoothly towards the edge of the
  // field. A correction fitted on half the images must remove most of it on
  // the other half, survive the model file, and 'none' must undo it.
  TrainingSet fitted{tinySet().spec()}, held_out{tinySet().spec()};
  tinySet().split(0.5, 2, fitted, held_out);
  Model model = createModel(tinySensor(), "resnet10_w16", 5);
  auto estimates = [&](const Model& m) {
    std::vector<const SparseSample*> picked;
    for (const auto& s : held_out.samples()) picked.push_back(&s);
    return m.predictSamples(picked);
  };
  auto rmsDeg = [&](const std::vector<Prediction>& p) {
    double sum = 0.0;
    for (std::size_t k = 0; k < p.size(); ++k)
      sum += std::pow(p[k].alpha_rad - held_out.samples()[k].alpha_rad, 2) +
             std::pow(p[k].beta_rad - held_out.samples()[k].beta_rad, 2);
    return radToDeg(std::sqrt(sum / (2.0 * static_cast<double>(p.size()))));
  };
  const std::vector<Prediction> raw = estimates(model);
  const BiasCalibration c = calibrateBias(model, fitted, 1000, 4);
  const std::vector<Prediction> corrected = estimates(model);
  std::printf("held-out RMS %.5f deg raw, %.5f deg with the degree-%d correction\n", rmsDeg(raw), rmsDeg(corrected),
              c.degree);
  EXPECT_GE(c.degree, 1);
  EXPECT_EQ(c.samples + c.outliers, fitted.size());
  EXPECT_LT(rmsDeg(corrected), 0.5 * rmsDeg(raw));

  const std::string path = tempPath("corrected.dssmodel");
  saveModel(model, path);
  const std::vector<Prediction> reloaded = estimates(loadModel(path));
  std::remove(path.c_str());
  for (std::size_t k = 0; k < corrected.size(); ++k) {
    EXPECT_DOUBLE_EQ(reloaded[k].alpha_rad, corrected[k].alpha_rad);
    EXPECT_DOUBLE_EQ(reloaded[k].beta_rad, corrected[k].beta_rad);
  }

  EXPECT_EQ(calibrateBias(model, fitted, 1000, AngleCorrection::kNone).degree, AngleCorrection::kNone);
  EXPECT_FALSE(model.meta.angle_correction.active());
  EXPECT_EQ(estimates(model)[0].alpha_rad, raw[0].alpha_rad);
  EXPECT_THROW(calibrateBias(model, fitted, 1000, AngleCorrection::kMaxDegree + 1), std::invalid_argument);
}

// A unit's refit on a few images: of low degree, added to the family's
// correction (which a low degree cannot replace) rather than instead of it.
TEST(BiasCalibration, AddsToTheModelsCorrection) {
  TrainingSet fitted{tinySet().spec()}, held_out{tinySet().spec()};
  tinySet().split(0.5, 2, fitted, held_out);
  std::vector<const SparseSample*> picked;
  for (const auto& s : held_out.samples()) picked.push_back(&s);
  auto rmsDeg = [&](const Model& m) {
    const auto p = m.predictSamples(picked);
    double sum = 0.0;
    for (std::size_t k = 0; k < p.size(); ++k)
      sum += std::pow(p[k].alpha_rad - picked[k]->alpha_rad, 2) + std::pow(p[k].beta_rad - picked[k]->beta_rad, 2);
    return radToDeg(std::sqrt(sum / (2.0 * static_cast<double>(p.size()))));
  };
  Model family = createModel(tinySensor(), "resnet10_w16", 5);
  calibrateBias(family, fitted, 1000, 4);
  const AngleCorrection base = family.meta.angle_correction;
  ASSERT_GE(base.degree, 1);
  Model replaced = family, added = family;
  calibrateBias(replaced, fitted, 1000, 0);
  const BiasCalibration c = calibrateBias(added, fitted, 1000, 0, true);
  const AngleCorrection& sum = added.meta.angle_correction;
  EXPECT_EQ(sum.degree, base.degree);
  // The base's terms above the added degree are untouched.
  for (std::size_t k = AngleCorrection::termCount(std::max(c.degree, 0)); k < sum.alpha.size(); ++k) {
    EXPECT_EQ(sum.alpha[k], base.alpha[k]) << k;
    EXPECT_EQ(sum.beta[k], base.beta[k]) << k;
  }
  std::printf("held-out RMS %.5f deg with the family's correction, %.5f added to, %.5f replaced by degree 0\n",
              rmsDeg(family), rmsDeg(added), rmsDeg(replaced));
  EXPECT_LT(rmsDeg(added), 1.05 * rmsDeg(family));
  EXPECT_LT(rmsDeg(added), 0.8 * rmsDeg(replaced));
}

// Averaged over the dihedral mirrors, each axis's variance mixes both of the
// head's outputs, so per-axis factors would not give the coverage they were
// fitted for: one factor serves both axes, and what calibrateSigma reports is
// what the model then predicts.
TEST(SigmaCalibration, DihedralModelCoversAsReported) {
  Model model = createModel(tinySensor(), "resnet10_w16", 5);
  model.net->eval();
  model.meta.inference_symmetry = InferenceSymmetry::kDihedral;
  const SigmaCalibration c = calibrateSigma(model, tinySet(), 160);
  EXPECT_EQ(c.scale_alpha, c.scale_beta);
  EXPECT_EQ(c.constant_sigma_alpha_rad, c.constant_sigma_beta_rad);
  std::vector<const SparseSample*> picked;
  for (std::size_t i = 0; i < 160; ++i) picked.push_back(&tinySet().samples()[i * tinySet().size() / 160]);
  std::vector<ErrorAndSigma> za, zb;
  for (std::size_t k = 0; k < picked.size(); ++k) {
    const Prediction p = model.predictSamples({picked[k]})[0];
    za.push_back({p.alpha_rad - picked[k]->alpha_rad, std::sqrt(p.alpha_variance_rad2)});
    zb.push_back({p.beta_rad - picked[k]->beta_rad, std::sqrt(p.beta_variance_rad2)});
  }
  for (int k = 0; k < 3; ++k) {
    EXPECT_NEAR(measureCoverage(za).within[k], c.alpha_after.within[k], 1e-9) << k;
    EXPECT_NEAR(measureCoverage(zb).within[k], c.beta_after.within[k], 1e-9) << k;
  }
}

// A constant sigma rescaled by a later calibration is still recorded as the
// constant it now is (the shipped models got a second calibration, which
// recorded "head").
TEST(SigmaCalibration, RescaledConstantStaysConstant) {
  Model model = createModel(tinySensor(), "resnet10_w16", 5);
  model.net->eval();
  EXPECT_FALSE(model.constantSigma());
  model.setConstantSigma(1e-3, 2e-3);
  ASSERT_TRUE(model.constantSigma());
  EXPECT_NEAR((*model.constantSigma())[1], 2e-3, 1e-9);
  const SigmaCalibration c = calibrateSigma(model, tinySet(), 160);
  EXPECT_TRUE(c.constant);
  const Prediction p = model.predictSamples({&tinySet().samples()[0]})[0];
  const double factor = c.site_law.factor(p.active_sites);  // 1 unless the lit-site law was fitted
  EXPECT_NEAR(std::sqrt(p.alpha_variance_rad2), c.constant_sigma_alpha_rad * factor,
              1e-6 * c.constant_sigma_alpha_rad * factor);
  EXPECT_NEAR(std::sqrt(p.beta_variance_rad2), c.constant_sigma_beta_rad * factor,
              1e-6 * c.constant_sigma_beta_rad * factor);
  const YAML::Node metrics = YAML::Load(model.meta.metrics_yaml);
  EXPECT_EQ(metrics["sigma_mode"].as<std::string>(), c.site_law.active() ? "lit_sites" : "constant");
  EXPECT_DOUBLE_EQ(metrics["sigma_constant_alpha_rad"].as<double>(), c.constant_sigma_alpha_rad);
  EXPECT_DOUBLE_EQ(metrics["sigma_constant_beta_rad"].as<double>(), c.constant_sigma_beta_rad);
}

// calibrate-unit's rule between 25 and 100 images: a sigma far too small
// for the errors is refitted, a sound or a generous one is left as it was.
TEST(SigmaCalibration, RefitsOnlyASigmaThatIsTooSmall) {
  Model model = createModel(tinySensor(), "resnet10_w16", 5);
  model.net->eval();
  model.setConstantSigma(1.0, 1.0);  // radians: every error within 1 sigma
  EXPECT_FALSE(calibrateSigmaWhereTooSmall(model, tinySet(), 160, 0.5));
  EXPECT_NEAR((*model.constantSigma())[0], 1.0, 1e-6);  // as set (the head holds it in float)
  model.setConstantSigma(1e-9, 1e-9);                   // none within 1 sigma
  const std::optional<SigmaCalibration> c = calibrateSigmaWhereTooSmall(model, tinySet(), 160, 0.5);
  ASSERT_TRUE(c);
  EXPECT_LT(c->alpha_before.within[0], 0.5);
  EXPECT_NEAR(c->alpha_after.within[0], 0.6827, 0.05);
  EXPECT_NEAR(c->beta_after.within[0], 0.6827, 0.05);
  const Prediction p = model.predictSamples({&tinySet().samples()[0]})[0];
  EXPECT_GT(std::sqrt(p.alpha_variance_rad2), 1e-6);  // the model holds the refitted sigma
}

}  // namespace
}  // namespace dss
