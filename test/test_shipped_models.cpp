// Every shipped model pinned to its headline figure: each recipe in
// config/recipes names the model's test bag (seed, offset, sampling) and its
// mean error per axis on it; the first images of that same bag, rendered here
// from the sensor recorded in the model file and estimated as `dss eval`
// does, must give a mean within 15 % of it. A model that no longer loads, a
// build that changes what a model estimates, or a recipe whose figure does
// not hold fails here.
#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/estimate/estimator_factory.h"
#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/sim/dataset_generator.h"
#include "digital_sun_sensor/sparse/threads.h"
#include "digital_sun_sensor/train/trainer.h"

namespace dss {
namespace {

constexpr double kTolerance = 0.15;

struct Pin {
  std::string model;
  DatasetSpec test;
  double alpha_mean_deg = 0.0, beta_mean_deg = 0.0;
};

Pin readRecipe(const std::string& model) {
  const YAML::Node r = YAML::LoadFile(std::string(DSS_SOURCE_DIR) + "/config/recipes/" + model + ".yaml");
  Pin pin;
  pin.model = model;
  const YAML::Node test = r["bags"]["test"];
  pin.test.seed = test["seed"].as<std::uint64_t>();
  pin.test.offset = test["offset"] ? test["offset"].as<std::uint64_t>() : 0;
  pin.test.sampling = parseSamplingMode(test["sampling"] ? test["sampling"].as<std::string>() : "random");
  pin.alpha_mean_deg = r["headline"]["alpha_mean_deg"].as<double>();
  pin.beta_mean_deg = r["headline"]["beta_mean_deg"].as<double>();
  return pin;
}

// Mean absolute error per axis (deg) over the valid estimates, and their count.
struct Measured {
  double alpha_mean_deg = 0.0, beta_mean_deg = 0.0;
  int valid = 0, images = 0;
};

struct LabelledImages {
  std::vector<cv::Mat> images;
  std::vector<ImageTruth> truths;
};

// The first `count` images of `spec` (seed, offset, sampling) of `sensor`.
LabelledImages render(const SensorConfig& sensor, DatasetSpec spec, int count) {
  spec.count = static_cast<std::uint64_t>(count);
  spec.threads = 2;
  LabelledImages set;
  DatasetGenerator(sensor, spec).run([&](const DatasetItem& item) {
    set.images.push_back(item.image);
    set.truths.push_back(item.truth);
  });
  return set;
}

// As `dss eval` estimates them (one thread, batches of 16).
Measured measure(SunEstimator& estimator, const LabelledImages& set) {
  sparse::configureThreads(1, 1);
  Measured m;
  m.images = static_cast<int>(set.images.size());
  constexpr std::size_t kBatch = 16;
  for (std::size_t first = 0; first < set.images.size(); first += kBatch) {
    const std::vector<cv::Mat> batch(set.images.begin() + first,
                                     set.images.begin() + std::min(set.images.size(), first + kBatch));
    const auto estimates = estimator.estimate(batch);
    for (std::size_t k = 0; k < estimates.size(); ++k) {
      if (!estimates[k].valid) continue;
      const ImageTruth& t = set.truths[first + k];
      m.alpha_mean_deg += std::abs(estimates[k].alpha_rad - t.alpha_rad) * kDegPerRad;
      m.beta_mean_deg += std::abs(estimates[k].beta_rad - t.beta_rad) * kDegPerRad;
      ++m.valid;
    }
  }
  if (m.valid > 0) {
    m.alpha_mean_deg /= m.valid;
    m.beta_mean_deg /= m.valid;
  }
  return m;
}

std::unique_ptr<SunEstimator> shippedModel(const std::string& model) {
  return makeEstimator("sscnn:" + std::string(DSS_SOURCE_DIR) + "/models/" + model + ".dssmodel");
}

// Over the first `count` images of the pin's test bag, of the sensor recorded in the model file.
Measured measure(const Pin& pin, int count) {
  const auto estimator = shippedModel(pin.model);
  return measure(*estimator, render(estimator->sensor(), pin.test, count));
}

void expectHeadline(const std::string& model, int count) {
  const Pin pin = readRecipe(model);
  const Measured m = measure(pin, count);
  ASSERT_EQ(m.images, count);
  EXPECT_GE(m.valid, static_cast<int>(0.98 * count)) << model;
  EXPECT_NEAR(m.alpha_mean_deg, pin.alpha_mean_deg, kTolerance * pin.alpha_mean_deg) << model << " alpha";
  EXPECT_NEAR(m.beta_mean_deg, pin.beta_mean_deg, kTolerance * pin.beta_mean_deg) << model << " beta";
  std::printf("%s: mean %.6f / %.6f deg on %d of %d images (headline %.6f / %.6f)\n", model.c_str(), m.alpha_mean_deg,
              m.beta_mean_deg, m.valid, m.images, pin.alpha_mean_deg, pin.beta_mean_deg);
}

// Every recipe has a model file and a pin below.
TEST(ShippedModels, EveryRecipeIsAShippedModel) {
  std::vector<std::string> recipes;
  for (const auto& e : std::filesystem::directory_iterator(std::string(DSS_SOURCE_DIR) + "/config/recipes"))
    recipes.push_back(e.path().stem().string());
  EXPECT_EQ(recipes.size(), 10u);
  for (const auto& r : recipes)
    EXPECT_TRUE(std::filesystem::exists(std::string(DSS_SOURCE_DIR) + "/models/" + r + ".dssmodel")) << r;
}

// Every recipe describes its model file: the recipe's sensor (with its `set`
// overrides) is the one the file records, its dss train options make the
// file's architecture and input encoding, and its schedule, data size and
// calibrate-sigma steps are the file's. Retraining takes hours
// (scripts/train_models.sh); this holds the recipes to the files in seconds.
TEST(ShippedModels, EveryRecipeDescribesItsModelFile) {
  const std::string source = DSS_SOURCE_DIR;
  for (const auto& e : std::filesystem::directory_iterator(source + "/config/recipes")) {
    const std::string name = e.path().stem().string();
    SCOPED_TRACE(name);
    const YAML::Node r = YAML::LoadFile(e.path().string());
    std::vector<std::string> sets;
    if (r["set"])
      for (const auto& s : r["set"]) sets.push_back(s.as<std::string>());
    const SensorConfig sensor =
        loadSensorConfig(source + "/config/sensors/" + r["sensor"].as<std::string>() + ".yaml", sets);
    const Model model = loadModel(source + "/models/" + name + ".dssmodel");
    const ModelMetadata& m = model.meta;
    EXPECT_EQ(toYaml(parseSensorConfig(m.sensor_yaml, name + " (recorded sensor)")), toYaml(sensor));

    const YAML::Node train = r["train"];
    TrainOptions options;
    options.arch = train["arch"].as<std::string>();
    options.centroid_weighting = train["centroid_weighting"].as<std::string>();
    options.feature_corrections = train["feature_corrections"].as<std::string>();
    if (train["lattice_phase"]) options.lattice_phase = train["lattice_phase"].as<std::string>();
    if (train["head"]) options.head = train["head"].as<std::string>();
    if (train["value_saturation"]) options.value_saturation = train["value_saturation"].as<double>();
    if (train["spot_readout"]) options.spot_readout = train["spot_readout"].as<std::string>();
    const FreshModelDesign design = freshModelDesign(sensor, options);
    const YAML::Node made = YAML::Load(metadataToYaml(metadataFor(sensor, design.arch, design.head)));
    const YAML::Node shipped = YAML::Load(metadataToYaml(m));
    EXPECT_EQ(YAML::Dump(made["arch"]), YAML::Dump(shipped["arch"]));
    EXPECT_EQ(YAML::Dump(made["input"]), YAML::Dump(shipped["input"]));

    const YAML::Node summary = YAML::Load(m.training_yaml);
    EXPECT_EQ(summary["epochs_scheduled"].as<int>(), train["epochs"].as<int>());
    EXPECT_DOUBLE_EQ(summary["learning_rate"].as<double>(), train["lr"].as<double>());
    EXPECT_EQ(summary["seed"].as<std::uint64_t>(), train["seed"].as<std::uint64_t>());
    EXPECT_FALSE(summary["init_model"]);
    std::uint64_t images = 0;
    for (const auto& bag : r["bags"]["train"]) images += bag["count"].as<std::uint64_t>();
    EXPECT_EQ(summary["train_samples"].as<std::uint64_t>() + summary["validation_samples"].as<std::uint64_t>(), images);

    // calibrate_sigma: keep leaves training's (no) angle correction, D fits one of degree <= D;
    // keep leaves no inference symmetry, another names it.
    const std::string correction = r["calibrate_sigma"]["correction_degree"].as<std::string>();
    if (correction == "keep" || correction == "none")
      EXPECT_FALSE(m.angle_correction.active());
    else
      EXPECT_TRUE(m.angle_correction.active() && m.angle_correction.degree <= std::stoi(correction));
    const std::string symmetry = r["calibrate_sigma"]["symmetry"].as<std::string>();
    EXPECT_EQ(inferenceSymmetryName(m.inference_symmetry), symmetry == "keep" ? std::string("none") : symmetry);
    // A family model: its sigma holds the error of an uncalibrated unit, and
    // its correction follows the mask height where the recipe fits that.
    const bool family = static_cast<bool>(r["calibrate_sigma"]["unit_tolerances"]);
    EXPECT_EQ(m.geometry_sigma_rad[0] > 0.0 && m.geometry_sigma_rad[1] > 0.0, family);
    const std::size_t heights = r["calibrate_height"] ? r["calibrate_height"]["changes_um"].size() : 0;
    EXPECT_EQ(m.height_corrections.size(), heights);
    // A spot bias where the recipe fits one, with its change at every height entry.
    const bool spot_bias = static_cast<bool>(r["calibrate_sigma"]["spot_bias_degree"]);
    EXPECT_EQ(m.spot_bias.active(), spot_bias);
    EXPECT_EQ(m.spot_bias.by_height.size(), spot_bias ? heights : 0);
    // A geometric head reading two spots or more flags model_mismatch beyond
    // twice the 99.5th percentile of its design's residuals over their median:
    // a few times the level. Thousands would flag no drifted unit (an
    // as-created thesis_ma head's residual, taken before the solve's last
    // step, gave 152 311).
    if (m.arch.geometric_head && sensor.mask.apertures.size() > 1) {
      EXPECT_GT(m.mismatch_level, 0.0);
      EXPECT_GT(m.mismatch_threshold, 1.0);
      EXPECT_LT(m.mismatch_threshold, 20.0);
    }
  }
}

TEST(ShippedModels, ThesisSa) { expectHeadline("thesis_sa", 400); }
TEST(ShippedModels, ThesisSaT50) { expectHeadline("thesis_sa_t50", 400); }
TEST(ShippedModels, ThesisMa) { expectHeadline("thesis_ma", 400); }
TEST(ShippedModels, WideMa) { expectHeadline("wide_ma", 300); }
TEST(ShippedModels, ThesisCa) { expectHeadline("thesis_ca", 150); }  // the pattern head: ~0.1 s per image
// The family models a built unit is calibrated from (geometric head), on their designs.
TEST(ShippedModels, ThesisSaFamily) { expectHeadline("thesis_sa_family", 400); }
TEST(ShippedModels, ThesisMaFamily) { expectHeadline("thesis_ma_family", 400); }
TEST(ShippedModels, WideMaFamily) { expectHeadline("wide_ma_family", 300); }

// The geometric heads as created (wide_ma's and the family models') publish
// nothing the backbone's features reach (angles from the spots through the
// geometry, the class from the position, feature corrections of zero
// weight, sigma from the lit sites or a constant): inference skips the
// backbone and publishes the same to the bit.
// thesis_ca's pattern head never runs the network; the other shipped models
// run their backbones.
TEST(ShippedModels, BackboneRunsOnlyWhereWhatIsPublishedReadsIt) {
  EXPECT_FALSE(loadModel(std::string(DSS_SOURCE_DIR) + "/models/thesis_ca.dssmodel").net->backboneNeeded());
  for (const std::string name :
       {"thesis_sa", "thesis_sa_t50", "thesis_ma", "thesis_sa_published", "thesis_ma_published"})
    EXPECT_TRUE(loadModel(std::string(DSS_SOURCE_DIR) + "/models/" + name + ".dssmodel").net->backboneNeeded()) << name;
  for (const std::string name : {"wide_ma", "wide_ma_family", "thesis_ma_family", "thesis_sa_family"}) {
    SCOPED_TRACE(name);
    Model m = loadModel(std::string(DSS_SOURCE_DIR) + "/models/" + name + ".dssmodel");
    m.net->eval();
    ASSERT_FALSE(m.net->backboneNeeded());
    DatasetSpec spec = readRecipe(name).test;
    spec.count = 6;
    std::vector<cv::Mat> images;
    DatasetGenerator(parseSensorConfig(m.meta.sensor_yaml, name), spec).run([&](const DatasetItem& item) {
      images.push_back(item.image);
    });
    const auto skipped = m.predict(images);
    m.net->setSkipUnusedBackbone(false);
    const auto full = m.predict(images);
    ASSERT_EQ(skipped.size(), full.size());
    for (std::size_t i = 0; i < full.size(); ++i) {
      EXPECT_EQ(skipped[i].alpha_rad, full[i].alpha_rad) << i;
      EXPECT_EQ(skipped[i].beta_rad, full[i].beta_rad) << i;
      EXPECT_EQ(skipped[i].alpha_variance_rad2, full[i].alpha_variance_rad2) << i;
      EXPECT_EQ(skipped[i].beta_variance_rad2, full[i].beta_variance_rad2) << i;
      EXPECT_EQ(skipped[i].subfov_class, full[i].subfov_class) << i;
      EXPECT_EQ(skipped[i].code_margin, full[i].code_margin) << i;
    }
    // A variance or feature corrections that read the features need the backbone again.
    torch::NoGradGuard no_grad;
    auto parameters = m.net->named_parameters();
    const torch::Tensor variance = parameters["variance.weight"].clone();
    parameters["variance.weight"].fill_(1e-3);
    EXPECT_TRUE(m.net->backboneNeeded());
    parameters["variance.weight"].copy_(variance);
    if (m.meta.arch.feature_corrections) {
      parameters["output.weight"].fill_(1e-3);
      EXPECT_TRUE(m.net->backboneNeeded());
    }
  }
}

// A unit calibrated from a family model keeps its input envelope and its
// network, so the family must answer stray-lit images and read them about as
// the sensor's shipped model does: made from nominal images only, thesis_sa's
// declined 68 % of them out_of_distribution, thesis_ma's 24 %. (thesis_ma's
// family trained on design images read them with a beta bias, 2.0 x the
// shipped model's mean here; the head as created, shipped since, has none.)
// Where the shipped model reads spots otherwise than its family (wide_ma's
// reads symmetric spots, 43 % less error under stray light: docs/results/
// wide_ma.md; its family centroids, no family with symmetric spots made
// yet), the family is held to the sensor's centroid baseline instead.
TEST(ShippedModels, FamilyModelsReadStrayLightAsTheShippedModels) {
  const std::string source = DSS_SOURCE_DIR;
  for (const std::string sensor : {"thesis_sa", "thesis_ma", "wide_ma"}) {
    const auto family = shippedModel(sensor + "_family");
    const bool alike = loadModel(source + "/models/" + sensor + ".dssmodel").meta.arch.geometric_symmetric_spots ==
                       loadModel(source + "/models/" + sensor + "_family.dssmodel").meta.arch.geometric_symmetric_spots;
    const auto shipped =
        alike ? shippedModel(sensor) : makeEstimator("centroid:" + source + "/models/" + sensor + ".calib.yaml");
    SensorConfig stray_lit = family->sensor();
    stray_lit.anomalies.stray_light_probability = 1.0;
    DatasetSpec spec = readRecipe(sensor + "_family").test;
    spec.seed = 611;  // fresh images, not the recipe's stray-lit sigma bag
    const LabelledImages set = render(stray_lit, spec, 100);
    const Measured f = measure(*family, set), s = measure(*shipped, set);
    EXPECT_GE(f.valid, 95) << sensor;
    EXPECT_LT(f.alpha_mean_deg, 1.25 * s.alpha_mean_deg) << sensor;
    EXPECT_LT(f.beta_mean_deg, 1.25 * s.beta_mean_deg) << sensor;
    std::printf("%s under stray light: family %.6f / %.6f deg on %d, shipped %s %.6f / %.6f deg on %d of %d images\n",
                sensor.c_str(), f.alpha_mean_deg, f.beta_mean_deg, f.valid, alike ? "model" : "baseline",
                s.alpha_mean_deg, s.beta_mean_deg, s.valid, f.images);
  }
}

TEST(ShippedModels, ThesisSaPublished) { expectHeadline("thesis_sa_published", 400); }
TEST(ShippedModels, ThesisMaPublished) { expectHeadline("thesis_ma_published", 400); }

}  // namespace
}  // namespace dss
