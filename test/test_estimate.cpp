// Runtime estimation around any estimator: the screens (saturation, predicted
// uncertainty, field of view), the SSCNN's input envelope, the estimator
// factory with its centroid fallback, and the uncertainty-coverage arithmetic.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <opencv2/imgproc.hpp>
#include <random>

#include "digital_sun_sensor/baseline/calibration.h"
#include "digital_sun_sensor/baseline/centroid_estimator.h"
#include "digital_sun_sensor/baseline/spot_extraction.h"
#include "digital_sun_sensor/common/estimate_status.h"
#include "digital_sun_sensor/common/spike_filter.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/estimate/estimator_factory.h"
#include "digital_sun_sensor/estimate/screened_estimator.h"
#include "digital_sun_sensor/eval/uncertainty.h"
#include "digital_sun_sensor/model/arch.h"
#include "digital_sun_sensor/model/input_envelope.h"
#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/model/sscnn_estimator.h"
#include "digital_sun_sensor/sim/geometry.h"
#include "digital_sun_sensor/sim/renderer.h"

namespace dss {
namespace {

SensorConfig shipped(const std::string& name) {
  return loadSensorConfig(std::string(DSS_SOURCE_DIR) + "/config/sensors/" + name + ".yaml");
}

std::string modelPath() { return std::string(DSS_SOURCE_DIR) + "/models/thesis_sa.dssmodel"; }
std::string calibrationPath() { return std::string(DSS_SOURCE_DIR) + "/models/thesis_sa.calib.yaml"; }

SunEstimate validEstimate(double alpha_deg, double beta_deg, double sigma_deg) {
  SunEstimate e;
  e.alpha_rad = alpha_deg * kRadPerDeg;
  e.beta_rad = beta_deg * kRadPerDeg;
  const double var = std::pow(sigma_deg * kRadPerDeg, 2);
  e.covariance = {var, 0.0, 0.0, var};
  e.valid = true;
  return e;
}

TEST(Screen, SaturatedImagesAreRejected) {
  ScreenOptions options;
  cv::Mat image(512, 512, CV_8UC1, cv::Scalar(0));
  EXPECT_EQ(screenImage(image, 255, options), "");
  image(cv::Rect(0, 0, 20, 20)).setTo(255);  // 400 px: a bright spot, 0.15 % of the detector
  EXPECT_EQ(screenImage(image, 255, options), "");
  image(cv::Rect(0, 0, 100, 100)).setTo(255);  // 3.8 %
  EXPECT_EQ(screenImage(image, 255, options), "saturated");
  cv::Mat deep(64, 64, CV_16UC1, cv::Scalar(4095));
  EXPECT_EQ(screenImage(deep, 4095, options), "saturated");
  EXPECT_EQ(screenImage(deep, 65535, options), "");
}

TEST(Screen, HotPixelsAreRemovedAndTheSpotKept) {
  cv::Mat image(64, 64, CV_8UC1, cv::Scalar(0));
  image(cv::Rect(20, 20, 6, 5)).setTo(200);  // a 30 px spot
  image.at<std::uint8_t>(3, 3) = 255;        // hot pixels: single, and a diagonal pair
  image.at<std::uint8_t>(50, 10) = 255;
  image.at<std::uint8_t>(51, 11) = 90;
  const cv::Mat cleaned = removeSmallSpots(image, 0.0, 0.0, 5);
  EXPECT_EQ(cv::countNonZero(cleaned), 30);
  EXPECT_EQ(cv::countNonZero(cleaned(cv::Rect(20, 20, 6, 5))), 30);
  EXPECT_EQ(cv::countNonZero(removeSmallSpots(image, 0.0, 0.0, 0)), 33);  // disabled
  // Raw readout: pixels at or under the threshold are background, not spots.
  cv::Mat raw(64, 64, CV_16UC1, cv::Scalar(100));
  raw(cv::Rect(30, 30, 4, 4)).setTo(900);
  raw.at<std::uint16_t>(5, 5) = 4000;
  const cv::Mat raw_cleaned = removeSmallSpots(raw, 120.0, 100.0, 5);
  EXPECT_EQ(raw_cleaned.at<std::uint16_t>(5, 5), 100);
  EXPECT_EQ(raw_cleaned.at<std::uint16_t>(31, 31), 900);
}

// The groups are OpenCV's 8-connected components: on seeded random images of
// every density (diagonal chains, shapes that join further down) the pixels
// kept are exactly those of components of at least min_px.
TEST(Screen, SmallGroupsAreOpenCvsEightConnectedComponents) {
  std::mt19937 rng(29);
  for (const double density : {0.05, 0.2, 0.4, 0.6}) {
    cv::Mat image(97, 131, CV_8UC1, cv::Scalar(0));
    std::bernoulli_distribution lit(density);
    for (int r = 0; r < image.rows; ++r)
      for (int c = 0; c < image.cols; ++c)
        if (lit(rng)) image.at<std::uint8_t>(r, c) = static_cast<std::uint8_t>(1 + rng() % 255);
    cv::Mat labels, stats, centroids;
    cv::connectedComponentsWithStats(image > 0, labels, stats, centroids, 8, CV_32S);
    for (const int min_px : {2, 5, 12}) {
      cv::Mat expected = image.clone();
      int removed = 0;
      for (int r = 0; r < image.rows; ++r)
        for (int c = 0; c < image.cols; ++c) {
          const int label = labels.at<int>(r, c);
          if (label > 0 && stats.at<int>(label, cv::CC_STAT_AREA) < min_px) {
            expected.at<std::uint8_t>(r, c) = 0;
            ++removed;
          }
        }
      EXPECT_EQ(cv::countNonZero(removeSmallSpots(image, 0.0, 0.0, min_px) != expected), 0)
          << "density " << density << ", min_px " << min_px;
      if (density == 0.2) {
        EXPECT_GT(removed, 0);
      }
    }
  }
}

// What the screen hands its estimator is what screenedImage gives a consumer
// that re-reads the image (in-flight recalibration): the hot pixel gone.
TEST(Screen, ScreenedImageIsWhatTheEstimatorIsGiven) {
  const SensorConfig sensor = shipped("thesis_sa");
  const ScreenedEstimator screen(std::make_unique<CentroidEstimator>(loadCalibration(calibrationPath())),
                                 ScreenOptions{});
  const Renderer renderer(SensorInstance::nominalOf(sensor));
  cv::Mat image = renderer.render(sunVectorFromAngles(0.5 * kRadPerDeg, -1.0 * kRadPerDeg), 7, nullptr, {});
  const cv::Mat clean = image.clone();
  image.at<std::uint8_t>(10, 10) = 255;  // a hot pixel far from the spot
  const cv::Mat screened = screen.screenedImage(image);
  EXPECT_EQ(screened.at<std::uint8_t>(10, 10), clean.at<std::uint8_t>(10, 10));
  EXPECT_EQ(cv::countNonZero(screened != clean), 0);
  EXPECT_TRUE(screen.screenedImage(cv::Mat()).empty());
}

// Hot pixels inside a real spot (wide_ma: 20 % on-chip threshold, sharp
// diffraction peaks) are found and repaired; the light itself is not touched,
// and the baseline's centroids return to those of the clean image.
TEST(SpikeFilter, HotPixelsInARenderedSpotAreRepairedAndItsLightIsNot) {
  const SensorConfig sensor = shipped("wide_ma");
  const std::vector<int> margins = spikeMargins(sensor, kDefaultSpikeSigmas);
  ASSERT_EQ(margins.size(), 256u);
  for (std::size_t m = 1; m < margins.size(); ++m) EXPECT_GE(margins[m], margins[m - 1]);
  EXPECT_TRUE(spikeMargins(sensor, 0.0).empty());
  EXPECT_THROW(spikeMargins(sensor, NAN), std::invalid_argument);

  const Renderer renderer(SensorInstance::draw(sensor, 5));
  SpotExtractionConfig with = SpotExtractionConfig::forSensor(sensor), without = with;
  without.spike_margin_dn.clear();
  std::mt19937 rng(11);
  int natural = 0;
  for (int i = 0; i < 4; ++i) {
    const cv::Mat clean =
        renderer.render(sunVectorFromAngles((12.0 - 9.0 * i) * kRadPerDeg, (7.0 * i - 20.0) * kRadPerDeg), 300 + i,
                        nullptr, RenderOptions{});
    int repaired = 0;
    repairSpikes(clean, margins, &repaired);
    natural += repaired;
    // Hot pixels of +120 DN on lit pixels of the spots, apart from each other.
    cv::Mat hot = clean.clone();
    std::vector<cv::Point> lit;
    cv::findNonZero(clean > 40, lit);
    ASSERT_GT(lit.size(), 200u);
    std::vector<cv::Point> placed;
    std::uniform_int_distribution<std::size_t> pick(0, lit.size() - 1);
    while (placed.size() < 6) {
      const cv::Point p = lit[pick(rng)];
      if (p.x < 1 || p.y < 1 || p.x >= hot.cols - 1 || p.y >= hot.rows - 1) continue;
      if (std::any_of(placed.begin(), placed.end(), [&](const cv::Point& q) { return cv::norm(p - q) < 3.0; }))
        continue;
      hot.at<std::uint8_t>(p) = cv::saturate_cast<std::uint8_t>(hot.at<std::uint8_t>(p) + 120);
      placed.push_back(p);
    }
    const cv::Mat fixed = repairSpikes(hot, margins, &repaired);
    EXPECT_GE(repaired, 6);
    for (const cv::Point& p : placed) {
      double lo = 255, hi = 0;
      cv::minMaxLoc(clean(cv::Rect(p.x - 1, p.y - 1, 3, 3)), &lo, &hi);
      EXPECT_GE(fixed.at<std::uint8_t>(p), lo) << p;
      EXPECT_LE(fixed.at<std::uint8_t>(p), hi) << p;
    }
    // The baseline's spots: back on the clean image's with the repair, off without it.
    const auto reference = extractSpots(clean, with), repaired_spots = extractSpots(hot, with),
               unrepaired = extractSpots(hot, without);
    ASSERT_EQ(repaired_spots.size(), reference.size());
    ASSERT_EQ(unrepaired.size(), reference.size());
    double worst_repaired = 0.0, worst_unrepaired = 0.0;
    for (const auto& r : reference) {
      auto nearest = [&](const std::vector<DetectedSpot>& spots) {
        double best = 1e9;
        for (const auto& s : spots) best = std::min(best, std::hypot(s.x_px - r.x_px, s.y_px - r.y_px));
        return best;
      };
      worst_repaired = std::max(worst_repaired, nearest(repaired_spots));
      worst_unrepaired = std::max(worst_unrepaired, nearest(unrepaired));
    }
    EXPECT_LT(worst_repaired, 0.015) << "image " << i;
    EXPECT_GT(worst_unrepaired, 0.03) << "image " << i;
  }
  EXPECT_LE(natural, 2) << "pixels of real light taken for spikes (1 in these 4 images)";
}

TEST(Screen, EstimatesBeyondTheEnvelopeAreRejected) {
  const SensorConfig sensor = shipped("thesis_sa");  // FOV +-4.54 deg
  ScreenOptions options;
  SunEstimate ok = validEstimate(1.0, -2.0, 0.001);
  screenEstimate(&ok, sensor, options);
  EXPECT_TRUE(ok.valid);

  SunEstimate unsure = validEstimate(1.0, -2.0, 0.05);
  screenEstimate(&unsure, sensor, options);
  EXPECT_FALSE(unsure.valid);
  EXPECT_EQ(unsure.status, "out_of_distribution");

  // A family model's unit-tolerance sigma (0.2 deg) is shared by every
  // estimate: the image's own (0.001 deg) is what is judged.
  SunEstimate family = validEstimate(1.0, -2.0, std::hypot(0.001, 0.2));
  family.model_sigma_rad = {degToRad(0.2), degToRad(0.2)};
  screenEstimate(&family, sensor, options);
  EXPECT_TRUE(family.valid);
  family.model_sigma_rad = {0.0, 0.0};
  screenEstimate(&family, sensor, options);
  EXPECT_EQ(family.status, "out_of_distribution");

  SunEstimate outside = validEstimate(4.9, 0.0, 0.001);
  screenEstimate(&outside, sensor, options);
  EXPECT_FALSE(outside.valid);
  EXPECT_EQ(outside.status, "outside_fov");

  SunEstimate nan = validEstimate(1.0, 1.0, 0.001);
  nan.covariance[3] = std::nan("");
  screenEstimate(&nan, sensor, options);
  EXPECT_EQ(nan.status, "out_of_distribution");

  options.max_sigma_deg = -1.0;
  EXPECT_THROW(options.validate(), std::invalid_argument);
  options = ScreenOptions{};
  options.spike_sigmas = -1.0;
  EXPECT_THROW(options.validate(), std::invalid_argument);
}

TEST(EstimatorFactory, ParsesSpecsAndChecksTheSensor) {
  EXPECT_THROW(makeEstimator("sscnn"), std::invalid_argument);
  EXPECT_THROW(makeEstimator("kalman:x.yaml"), std::invalid_argument);
  const SensorConfig sa = shipped("thesis_sa"), wide = shipped("wide_ma");
  EXPECT_EQ(makeEstimator("sscnn:" + modelPath(), &sa)->source(), "sscnn");
  EXPECT_EQ(makeEstimator("centroid:" + calibrationPath(), &sa)->source(), "centroid");
  EXPECT_THROW(makeEstimator("sscnn:" + modelPath(), &wide), std::runtime_error);
  try {
    makeEstimator("centroid:" + calibrationPath(), &wide);
    ADD_FAILURE() << "a thesis_sa calibration was accepted for wide_ma";
  } catch (const CalibrationError& e) {
    EXPECT_NE(std::string(e.what()).find("wide_ma"), std::string::npos) << e.what();
  }
  // The whole-pattern estimator takes the sensor config itself.
  const std::string ca = std::string(DSS_SOURCE_DIR) + "/config/sensors/thesis_ca.yaml";
  const SensorConfig coded = shipped("thesis_ca");
  EXPECT_EQ(makeEstimator("pattern:" + ca, &coded)->source(), "pattern");
  EXPECT_THROW(makeEstimator("pattern:" + ca, &sa), std::invalid_argument);
  // A merged-spot sensor falls back to its whole-pattern estimator.
  EstimatorChoice pattern = chooseEstimator("", kPatternFallback, coded);
  ASSERT_TRUE(pattern.estimator) << pattern.problem;
  EXPECT_EQ(pattern.estimator->source(), "pattern");
  EXPECT_TRUE(pattern.is_fallback);
  // The node's screen passes the hints of the images it lets through.
  ScreenedEstimator screened(std::move(pattern.estimator), ScreenOptions{});
  RenderOptions clean;
  clean.noise = false;
  const cv::Mat image = Renderer(SensorInstance::nominalOf(coded))
                            .render(sunVectorFromAngles(degToRad(-3.0), degToRad(1.0)), 1, nullptr, clean);
  const SunEstimate hinted = screened.estimateWithSubFovHints({image}, {quadrantClass(degToRad(-3.0), 0.1)}).at(0);
  ASSERT_TRUE(hinted.valid) << hinted.status;
  EXPECT_NEAR(radToDeg(hinted.alpha_rad), -3.0, 1e-3);
  // Only an estimator that can use a sub-FOV hint takes one.
  EXPECT_THROW(makeEstimator("centroid:" + calibrationPath(), &sa)->estimateWithSubFovHints({}, {}),
               std::invalid_argument);
}

// The shipped thesis_sa model averages over its 8 mirror images; the option
// sets that aside (calibration_node's ~inference_symmetry: none).
TEST(EstimatorFactory, MirrorAverageCanBeSetAside) {
  EXPECT_TRUE(mirrorAverageFromName("model"));
  EXPECT_FALSE(mirrorAverageFromName("none"));
  try {
    mirrorAverageFromName("dihedral");
    ADD_FAILURE() << "'dihedral' was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("'dihedral'"), std::string::npos) << e.what();
  }
  const SensorConfig sa = shipped("thesis_sa");
  const SscnnEstimator averaged(modelPath(), &sa), alone(modelPath(), &sa, false);
  EXPECT_EQ(averaged.inferenceSymmetry(), "dihedral");
  EXPECT_EQ(alone.inferenceSymmetry(), "none");
  EstimatorChoice choice = chooseEstimator(modelPath(), calibrationPath(), sa, EstimatorOptions{false});
  ASSERT_TRUE(choice.estimator);
  EXPECT_EQ(dynamic_cast<const SscnnEstimator&>(*choice.estimator).inferenceSymmetry(), "none");
}

TEST(EstimatorFactory, FallsBackToTheCentroidBaselineAndSaysWhy) {
  const SensorConfig sa = shipped("thesis_sa");
  EstimatorChoice primary = chooseEstimator(modelPath(), calibrationPath(), sa);
  ASSERT_TRUE(primary.estimator);
  EXPECT_EQ(primary.estimator->source(), "sscnn");
  EXPECT_FALSE(primary.is_fallback);
  EXPECT_EQ(primary.problem, "");

  // A truncated model file: the centroid baseline takes over.
  const std::string broken = ::testing::TempDir() + "dss_broken.dssmodel";
  {
    std::FILE* f = std::fopen(broken.c_str(), "wb");
    std::fputs("DSSMODEL truncated", f);
    std::fclose(f);
  }
  EstimatorChoice fallback = chooseEstimator(broken, calibrationPath(), sa);
  ASSERT_TRUE(fallback.estimator);
  EXPECT_EQ(fallback.estimator->source(), "centroid");
  EXPECT_TRUE(fallback.is_fallback);
  EXPECT_NE(fallback.problem.find(broken), std::string::npos) << fallback.problem;

  EstimatorChoice none = chooseEstimator("", "", sa);
  EXPECT_FALSE(none.estimator);
  EXPECT_NE(none.problem.find("no model file"), std::string::npos) << none.problem;
  EXPECT_NE(none.problem.find("no calibration file"), std::string::npos) << none.problem;
  std::remove(broken.c_str());
}

TEST(InputEnvelope, QuantilesWidenedAndUnknownAcceptsAll) {
  std::vector<int> counts;
  for (int i = 0; i < 1000; ++i) counts.push_back(100 + i % 50);
  const InputEnvelope e = measureInputEnvelope(counts);
  EXPECT_EQ(e.min_sites, 80);   // floor(100 / 1.25)
  EXPECT_EQ(e.max_sites, 187);  // ceil(149 * 1.25)
  EXPECT_TRUE(e.contains(80));
  EXPECT_FALSE(e.contains(79));
  EXPECT_FALSE(e.contains(188));
  EXPECT_FALSE(measureInputEnvelope({}).known());
  EXPECT_TRUE(InputEnvelope{}.contains(100000));
  // Training envelope widened by the sigma-calibration images'.
  const InputEnvelope both = covering(e, InputEnvelope{120, 400});
  EXPECT_EQ(both.min_sites, 80);
  EXPECT_EQ(both.max_sites, 400);
  EXPECT_EQ(covering(InputEnvelope{}, e).max_sites, 187);
  EXPECT_EQ(covering(e, InputEnvelope{}).min_sites, 80);
}

// The SSCNN estimator answers out_of_distribution when an image's lit pixels
// lie outside the envelope recorded in the model, and estimates it otherwise.
TEST(InputEnvelope, SscnnEstimatorFlagsImagesOutsideIt) {
  const SensorConfig sa = shipped("thesis_sa");
  cv::Mat image(512, 512, CV_8UC1, cv::Scalar(0));
  cv::circle(image, {261, 240}, 6, cv::Scalar(200), cv::FILLED);  // 113 lit pixels
  const int lit = cv::countNonZero(image);
  Model model = loadModel(modelPath(), &sa);
  const std::string path = ::testing::TempDir() + "dss_envelope.dssmodel";
  auto estimateWith = [&](InputEnvelope envelope) {
    recordInputEnvelope(model.meta, envelope);
    saveModel(model, path);
    return SscnnEstimator(path, &sa).estimate({image}).front();
  };
  const SunEstimate inside = estimateWith({lit / 2, lit * 2});
  EXPECT_TRUE(inside.valid) << inside.status;
  const SunEstimate outside = estimateWith({lit + 10, lit * 2});
  EXPECT_FALSE(outside.valid);
  EXPECT_EQ(outside.status.rfind("out_of_distribution: " + std::to_string(lit) + " lit pixels", 0), 0u)
      << outside.status;
  std::remove(path.c_str());
}

TEST(Uncertainty, CoverageAndScaleOfGaussianErrors) {
  std::mt19937_64 rng(5);
  std::normal_distribution<double> normal(0.0, 1.0);
  std::vector<ErrorAndSigma> honest, pessimistic;
  for (int i = 0; i < 20000; ++i) {
    const double sigma = 0.5 + (i % 7) * 0.25;  // varying per sample, like the SSCNN's
    const double error = sigma * normal(rng);
    honest.push_back({error, sigma});
    pessimistic.push_back({error, 4.0 * sigma});
  }
  const Coverage c = measureCoverage(honest);
  EXPECT_NEAR(c.within[0], 0.6827, 0.01);
  EXPECT_NEAR(c.within[1], 0.9545, 0.005);
  EXPECT_NEAR(c.within[2], 0.9973, 0.002);
  EXPECT_NEAR(sigmaScaleForCoverage(honest), 1.0, 0.03);
  EXPECT_GT(measureCoverage(pessimistic).within[0], 0.95);
  EXPECT_NEAR(sigmaScaleForCoverage(pessimistic), 0.25, 0.01);
  EXPECT_EQ(measureCoverage({{1.0, 0.0}}).within[2], 0.0);  // no sigma: outside
  EXPECT_EQ(sigmaScaleForCoverage({}), 1.0);
}

// Errors whose spread falls as the square root of the lit-site count: the
// fitted law finds the exponent and covers every quarter of the counts, where
// one constant sigma over-covers the many-site images and under-covers the
// few-site ones; with a spread that does not follow the count, the law stays
// (nearly) constant.
TEST(Uncertainty, SiteSigmaLawFollowsTheLitSiteCount) {
  std::mt19937_64 rng(11);
  std::normal_distribution<double> normal(0.0, 1.0);
  std::uniform_int_distribution<int> count(50, 800);
  std::vector<SitedError> following, flat;
  for (int i = 0; i < 8000; ++i) {
    const int n = count(rng);
    following.push_back({1e-5 * std::sqrt(200.0 / n) * normal(rng), n});
    flat.push_back({1e-5 * normal(rng), n});
  }
  const SiteSigmaLaw law = fitSiteSigmaLaw({following});
  EXPECT_NEAR(law.exponent, 0.5, 0.1);
  EXPECT_NEAR(law.reference_sites, 425.0, 25.0);  // the median count
  EXPECT_NEAR(law.factor(4.0 * law.reference_sites), std::pow(4.0, -law.exponent), 1e-12);
  auto quarterCoverage = [&](const SiteSigmaLaw& l) {
    std::vector<ErrorAndSigma> z;
    for (const auto& s : following) z.push_back({s.error_rad, l.factor(s.sites)});
    const double scale = sigmaScaleForCoverage(z);
    std::array<std::vector<ErrorAndSigma>, 2> few_many;  // below 150 and above 650 lit sites
    for (std::size_t k = 0; k < z.size(); ++k)
      if (following[k].sites < 150 || following[k].sites > 650)
        few_many[following[k].sites > 650].push_back({z[k].error_rad, z[k].sigma_rad * scale});
    return std::array<double, 2>{measureCoverage(few_many[0]).within[0], measureCoverage(few_many[1]).within[0]};
  };
  const auto fitted = quarterCoverage(law), constant = quarterCoverage({});
  EXPECT_NEAR(fitted[0], 0.6827, 0.04);
  EXPECT_NEAR(fitted[1], 0.6827, 0.04);
  EXPECT_LT(constant[0], 0.55);  // few sites: larger errors than one sigma says
  EXPECT_GT(constant[1], 0.80);
  EXPECT_LE(std::abs(fitSiteSigmaLaw({flat}).exponent), 0.1);
  EXPECT_FALSE(fitSiteSigmaLaw({{{1e-5, 100}}}).active());  // too few samples
  EXPECT_EQ(SiteSigmaLaw{}.factor(10.0), 1.0);
}

// Every estimate status an image can cause has an image here that causes it,
// through the estimators and screens calibration_node runs. (Elsewhere:
// out_of_distribution from lit pixels, InputEnvelope.SscnnEstimatorFlagsImagesOutsideIt;
// ambiguous_aperture, LatticeHead tests; bad_image and no_estimator over ROS,
// calibration_input.test.)
TEST(Status, EveryImageStatusHasAnImageThatCausesIt) {
  const SensorConfig sa =
      loadSensorConfig(std::string(DSS_SOURCE_DIR) + "/config/sensors/thesis_sa.yaml", {"optics.psf_node_step_deg=3"});
  const Renderer renderer(SensorInstance::draw(sa, 1));
  auto sunAt = [&](double alpha_deg, double beta_deg) {
    return renderer.render(sunVectorFromAngles(alpha_deg * kRadPerDeg, beta_deg * kRadPerDeg), 7, nullptr,
                           RenderOptions{});
  };
  auto code = [](const SunEstimate& e) { return status::statusCode(e.status); };
  const SensorConfig design = shipped("thesis_sa");
  ScreenedEstimator sscnn(std::make_unique<SscnnEstimator>(modelPath(), &design), ScreenOptions{});
  ScreenedEstimator centroid(std::make_unique<CentroidEstimator>(loadCalibration(calibrationPath())), ScreenOptions{});

  const cv::Mat dark(512, 512, CV_8UC1, cv::Scalar(0));  // eclipse
  EXPECT_EQ(code(sscnn.estimate({dark})[0]), status::kNoSun);
  EXPECT_EQ(code(centroid.estimate({dark})[0]), status::kNoSun);
  const cv::Mat blinded(512, 512, CV_8UC1, cv::Scalar(255));
  EXPECT_EQ(code(sscnn.estimate({blinded})[0]), status::kSaturated);
  const cv::Mat small(256, 256, CV_8UC1, cv::Scalar(0));
  EXPECT_EQ(code(sscnn.estimate({small})[0]), status::kBadImage);
  EXPECT_EQ(code(centroid.estimate({small})[0]), status::kBadImage);

  // The sun inside the detector's view but outside the field of view a
  // sensor declares (narrowed to 3 deg here), through the screen.
  SunEstimate beyond = sscnn.estimate({sunAt(4.0, 0.0)})[0];
  ASSERT_TRUE(beyond.valid) << beyond.status;
  SensorConfig narrow = design;
  narrow.fov.alpha_max_deg = 3.0;
  screenEstimate(&beyond, narrow, ScreenOptions{});
  EXPECT_FALSE(beyond.valid);
  EXPECT_EQ(code(beyond), status::kOutsideFov) << beyond.status;

  // The baseline's spot cut by the detector edge.
  const SunEstimate cut = centroid.estimate({sunAt(4.45, 0.0)})[0];
  EXPECT_FALSE(cut.valid);
  EXPECT_EQ(code(cut), status::kSpotAtEdge) << cut.status;

  // A geometric-head model whose calibrated spot residual level the image's
  // spots exceed by far: model_mismatch (the level is set tiny here; a real
  // case is an uncalibrated unit, UnitCalibration tests).
  const SensorConfig ma =
      loadSensorConfig(std::string(DSS_SOURCE_DIR) + "/config/sensors/thesis_ma.yaml", {"optics.psf_node_step_deg=3"});
  HeadOptions geometric;
  geometric.head = "geometric";
  Model model = createModel(ma, archPreset("resnet10_w16", ma.numSubFovClasses()), 1, geometric);
  model.meta.mismatch_level = 1e-12;
  model.meta.mismatch_threshold = 3.0;
  const std::string path = ::testing::TempDir() + "dss_status_geometric.dssmodel";
  saveModel(model, path);
  const Renderer ma_renderer(SensorInstance::draw(ma, 1));
  const cv::Mat ma_image =
      ma_renderer.render(sunVectorFromAngles(0.5 * kRadPerDeg, -0.3 * kRadPerDeg), 7, nullptr, RenderOptions{});
  const SunEstimate mismatch = SscnnEstimator(path, &ma).estimate({ma_image})[0];
  EXPECT_FALSE(mismatch.valid);
  EXPECT_EQ(code(mismatch), status::kModelMismatch) << mismatch.status;
  std::remove(path.c_str());
}

}  // namespace
}  // namespace dss
