// The pattern head (a mask whose spots merge, thesis_ca): `auto` picks it,
// it answers as the sensor design's whole-pattern estimator does on the
// same images (from the sites alone: every lit pixel is one), its input
// envelope counts what it sees, its file round-trips, it never runs the
// network, and it is refused where the sites are not the whole image.
#include <gtest/gtest.h>

#include "digital_sun_sensor/baseline/pattern_estimator.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/model/sparse_input.h"
#include "digital_sun_sensor/sim/dataset_generator.h"
#include "digital_sun_sensor/sim/geometry.h"
#include "digital_sun_sensor/sim/renderer.h"
#include "digital_sun_sensor/train/training_set.h"

namespace dss {
namespace {

SensorConfig shipped(const std::string& name) {
  return loadSensorConfig(std::string(DSS_SOURCE_DIR) + "/config/sensors/" + name + ".yaml");
}

TEST(PatternHead, MergedSpotsGetItAndItAnswersAsThePatternEstimator) {
  const SensorConfig config = shipped("thesis_ca");
  const ArchSpec arch = archPreset("resnet10_w16", config.numSubFovClasses());
  Model model = createModel(config, arch, 3);  // head "auto"
  ASSERT_TRUE(model.meta.arch.pattern_head);
  EXPECT_FALSE(model.meta.arch.geometric_head);
  EXPECT_EQ(model.meta.input.max_sites, config.detector.width_px * config.detector.height_px);
  EXPECT_FALSE(model.net->backboneNeeded());
  // The other shipped masks keep their heads, which take no coarse direction.
  for (const std::string name : {"thesis_sa", "thesis_ma", "wide_ma"}) {
    const Model other = createModel(shipped(name), arch, 3);
    EXPECT_FALSE(other.meta.arch.pattern_head) << name;
    const SensorConfig sensor = shipped(name);
    const cv::Mat dark = cv::Mat::zeros(sensor.detector.height_px, sensor.detector.width_px, CV_8U);
    const CoarseDirections coarse = {CoarseDirection{0.0, 0.0, 0.01}};
    EXPECT_THROW(other.predict({dark}, &coarse), std::invalid_argument) << name;
  }

  DatasetSpec spec;
  spec.count = 4;
  spec.seed = 8831;
  std::vector<cv::Mat> images;
  DatasetGenerator(config, spec).run([&](const DatasetItem& item) { images.push_back(item.image); });
  images.push_back(cv::Mat::zeros(images[0].size(), images[0].type()));  // no sun

  PatternEstimatorOptions options;
  options.sigma_images = 0;
  PatternEstimator reference(config, options);
  const auto expected = reference.estimate(images);
  model.net->eval();
  const Model loaded = deserializeModel(serializeModel(model), "pattern.dssmodel", &config);
  ASSERT_TRUE(loaded.meta.arch.pattern_head);
  for (const Model* m : {static_cast<const Model*>(&model), &loaded}) {
    const auto predicted = m->predict(images);
    ASSERT_EQ(predicted.size(), images.size());
    for (std::size_t i = 0; i + 1 < images.size(); ++i) {
      ASSERT_TRUE(expected[i].valid) << i << ": " << expected[i].status;
      EXPECT_TRUE(predicted[i].declined.empty()) << i;
      // The head's angles pass through the network's float precision.
      EXPECT_NEAR(predicted[i].alpha_rad, expected[i].alpha_rad, 1e-8) << i;
      EXPECT_NEAR(predicted[i].beta_rad, expected[i].beta_rad, 1e-8) << i;
      EXPECT_NEAR(predicted[i].alpha_variance_rad2, expected[i].covariance[0], 1e-5 * expected[i].covariance[0]) << i;
      EXPECT_NEAR(predicted[i].beta_variance_rad2, expected[i].covariance[3], 1e-5 * expected[i].covariance[3]) << i;
      EXPECT_EQ(predicted[i].subfov_class, expected[i].subfov_class) << i;
    }
    EXPECT_EQ(predicted.back().active_sites, 0);
    // predict() solves the images its sites make without the sparse tensor:
    // the same predictions to the bit as through it.
    const auto input = encodeImages(images, m->meta.input);
    const auto through_sites = m->decode(m->net->forward(input), *input.sites);
    for (std::size_t i = 0; i < images.size(); ++i) {
      EXPECT_EQ(predicted[i].alpha_rad, through_sites[i].alpha_rad) << i;
      EXPECT_EQ(predicted[i].beta_rad, through_sites[i].beta_rad) << i;
      EXPECT_EQ(predicted[i].alpha_variance_rad2, through_sites[i].alpha_variance_rad2) << i;
      EXPECT_EQ(predicted[i].active_sites, through_sites[i].active_sites) << i;
      EXPECT_EQ(predicted[i].declined, through_sites[i].declined) << i;
    }
  }
  // The input envelope is measured on what the head sees: every lit pixel,
  // more than the 16384 sites a data set's own spec keeps (an envelope
  // measured on those refused every image as out_of_distribution).
  TrainingSet data(inputSpecFor(config));
  for (const cv::Mat& image : images) data.add(image, 0.0, 0.0, 0);
  const auto counts = data.siteCounts(model.meta.input.max_sites);
  const auto predicted = model.predict(images);
  for (std::size_t i = 0; i < images.size(); ++i) EXPECT_EQ(counts[i], predicted[i].active_sites) << i;
  EXPECT_GT(counts[0], inputSpecFor(config).max_sites);
}

// A constant sigma (what calibrate-sigma fits where the solve's own has
// the wrong shape) still grows with the light the design does not hold,
// as the pattern estimator's own does.
TEST(PatternHead, ConstantSigmaGrowsWithLightTheDesignLacks) {
  const SensorConfig config = shipped("thesis_ca");
  Model model = createModel(config, archPreset("resnet10_w16", config.numSubFovClasses()), 3);
  ASSERT_TRUE(model.meta.arch.pattern_head);
  const double sigma_alpha = 2e-6, sigma_beta = 3e-6;
  model.setConstantSigma(sigma_alpha, sigma_beta);
  model.net->eval();
  SensorConfig ghostly = config;
  ghostly.anomalies.ghost_probability = 1.0;
  const Eigen::Vector3d sun = sunVectorFromAngles(degToRad(1.5), degToRad(-1.0));
  const std::vector<cv::Mat> images = {Renderer(SensorInstance::draw(config, 7)).render(sun, 2, nullptr),
                                       Renderer(SensorInstance::draw(ghostly, 7)).render(sun, 2, nullptr)};
  PatternEstimatorOptions options;
  options.sigma_images = 0;
  const auto expected = PatternEstimator(config, options).estimate(images);
  const auto predicted = model.predict(images);
  for (std::size_t i = 0; i < images.size(); ++i) {
    ASSERT_TRUE(expected[i].valid && predicted[i].declined.empty()) << i << ": " << expected[i].status;
    const double inflation = PatternEstimator::varianceInflation(expected[i].unexplained_light_z);
    EXPECT_NEAR(predicted[i].alpha_variance_rad2, sigma_alpha * sigma_alpha * inflation,
                1e-5 * sigma_alpha * sigma_alpha * inflation)
        << i;
    EXPECT_NEAR(predicted[i].beta_variance_rad2, sigma_beta * sigma_beta * inflation,
                1e-5 * sigma_beta * sigma_beta * inflation)
        << i;
  }
  EXPECT_LT(expected[0].unexplained_light_z, PatternEstimator::kExcessNoiseZ);  // no ghost: the constant
  EXPECT_GT(PatternEstimator::varianceInflation(expected[1].unexplained_light_z), 2.5);
}

TEST(PatternHead, NeedsAnOnChipThreshold) {
  SensorConfig config = shipped("thesis_sa");
  const ArchSpec arch = archPreset("resnet10_w16", config.numSubFovClasses());
  HeadOptions head;
  head.head = "pattern";
  EXPECT_TRUE(createModel(config, arch, 3, head).meta.arch.pattern_head);  // any mask, when asked
  config.threshold.enabled = false;
  try {
    createModel(config, arch, 3, head);
    ADD_FAILURE() << "a pattern head without an on-chip threshold";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("thresholds on chip"), std::string::npos) << e.what();
  }
  head.head = "patterns";
  EXPECT_THROW(createModel(shipped("thesis_sa"), arch, 3, head), std::invalid_argument);
}

}  // namespace
}  // namespace dss
