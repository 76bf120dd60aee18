// The Cramer-Rao bound against the closed form for a Gaussian spot under
// Poisson noise, and the maximum-likelihood fit reaching it.
#include <gtest/gtest.h>

#include <cstdio>
#include <limits>

#include <Eigen/Dense>
#include <cmath>

#include "digital_sun_sensor/baseline/gaussian_fit.h"
#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/eval/crlb.h"
#include "digital_sun_sensor/sim/geometry.h"
#include "digital_sun_sensor/sim/sensor_instance.h"

namespace dss {
namespace {

constexpr int kPatch = 25;

GaussianSpot shifted(GaussianSpot s, int parameter, double delta) {
  double* fields[5] = {&s.x, &s.y, &s.sigma, &s.total, &s.background};
  *fields[parameter] += delta;
  return s;
}

// d(expected image)/d(x, y, sigma, total, background) by central differences.
std::vector<cv::Mat> spotDerivatives(const GaussianSpot& s) {
  std::vector<cv::Mat> out;
  for (int k = 0; k < 5; ++k) {
    const double h = k == 3 ? 1e-3 * s.total : 1e-5;
    out.push_back(
        (renderGaussianSpot(shifted(s, k, h), kPatch, kPatch) - renderGaussianSpot(shifted(s, k, -h), kPatch, kPatch)) /
        (2 * h));
  }
  return out;
}

// Pure Poisson, no background: the pixel-integrated bound tends to the
// continuous closed form sigma^2 / N as pixels shrink against the spot, and
// follows the standard pixelation correction (sigma^2 + a^2/12) / N.
TEST(Crlb, MatchesClosedFormForGaussianSpotUnderPoisson) {
  for (const double sigma : {1.5, 3.0}) {
    const GaussianSpot spot{12.3, 11.8, sigma, 1.0e4, 0.0};
    const cv::Mat mean = renderGaussianSpot(spot, kPatch, kPatch);
    auto d = spotDerivatives(spot);
    d.resize(2);  // position only: known width and flux
    const Eigen::MatrixXd fisher = fisherInformation(mean, d, [](double mu) { return mu; });
    const double bound_x = Eigen::MatrixXd(fisher.inverse())(0, 0), bound_y = Eigen::MatrixXd(fisher.inverse())(1, 1);
    const double pixelated = (sigma * sigma + 1.0 / 12.0) / spot.total;
    EXPECT_NEAR(bound_x / pixelated, 1.0, 0.01) << "sigma " << sigma;
    EXPECT_NEAR(bound_y / pixelated, 1.0, 0.01) << "sigma " << sigma;
    EXPECT_NEAR(bound_x / (sigma * sigma / spot.total), 1.0, sigma > 2 ? 0.015 : 0.05) << "sigma " << sigma;
  }
}

// Monte Carlo: the Poisson maximum-likelihood fit with every parameter free
// is efficient; its RMS position error sits within 10% of the bound (1000
// trials: the RMS itself is known to ~2%).
TEST(Crlb, MaximumLikelihoodFitReachesTheBound) {
  const GaussianSpot truth{12.2, 11.7, 1.6, 5.0e3, 3.0};
  const cv::Mat mean = renderGaussianSpot(truth, kPatch, kPatch);
  const Eigen::MatrixXd fisher = fisherInformation(mean, spotDerivatives(truth), [](double mu) { return mu; });
  const Eigen::MatrixXd bound = fisher.inverse();
  Rng rng(2024);
  double sum_sq_x = 0.0, sum_sq_y = 0.0;
  const int trials = 1000;
  for (int t = 0; t < trials; ++t) {
    cv::Mat counts(kPatch, kPatch, CV_64F);
    for (int r = 0; r < kPatch; ++r)
      for (int c = 0; c < kPatch; ++c)
        counts.at<double>(r, c) = static_cast<double>(rng.poisson(mean.at<double>(r, c)));
    const GaussianSpot start{12.0, 12.0, 2.0, cv::sum(counts)[0], 1.0};
    const GaussianFitResult fit = fitGaussianSpot(counts, start);
    ASSERT_TRUE(fit.converged);
    sum_sq_x += std::pow(fit.spot.x - truth.x, 2);
    sum_sq_y += std::pow(fit.spot.y - truth.y, 2);
  }
  EXPECT_NEAR(std::sqrt(sum_sq_x / trials) / std::sqrt(bound(0, 0)), 1.0, 0.10);
  EXPECT_NEAR(std::sqrt(sum_sq_y / trials) / std::sqrt(bound(1, 1)), 1.0, 0.10);
}

// The sensor-level bound: finite, positive, symmetric between the axes at
// 45 deg, and it falls as the square root of the light (shot-noise limited).
TEST(Crlb, SensorBoundScalesWithLight) {
  const auto path = std::string(DSS_SOURCE_DIR) + "/config/sensors/thesis_sa.yaml";
  const std::vector<std::string> base = {"optics.psf_node_step_deg=3",
                                         "exposure.mode=fixed",
                                         "detector_noise.read_noise_e=0",
                                         "detector_noise.prnu_fraction=0",
                                         "detector_noise.dark_current_e_per_s=0",
                                         "detector_noise.bit_depth=16"};
  auto with = [&](const std::string& exposure) {
    auto o = base;
    o.push_back("exposure.exposure_s=" + exposure);
    return CrlbCalculator(loadSensorConfig(path, o)).covariance(0.01, 0.01);
  };
  const Eigen::Matrix2d dim = with("2e-5"), bright = with("8e-5");
  ASSERT_TRUE(dim.allFinite());
  EXPECT_GT(dim(0, 0), 0.0);
  EXPECT_NEAR(dim(0, 0) / dim(1, 1), 1.0, 0.02);
  EXPECT_NEAR(dim(0, 0) / bright(0, 0), 4.0, 0.1);
}

// A threshold censors pixels below it: the Tobit information share is 1 far
// above, 0 far below and 1/2 + 1/pi at the mean; the sensor's bound with its
// on-chip threshold is weaker than the raw readout's, and equal without one.
TEST(Crlb, ThresholdCensoringLosesInformation) {
  EXPECT_EQ(censoredInformationShare(-std::numeric_limits<double>::infinity()), 1.0);
  EXPECT_NEAR(censoredInformationShare(-8.0), 1.0, 1e-9);
  EXPECT_NEAR(censoredInformationShare(0.0), 0.5 + 1.0 / 3.14159265358979323846, 1e-12);
  EXPECT_LT(censoredInformationShare(6.0), 1e-6);
  for (double a = -5; a < 5; a += 0.25)
    EXPECT_GE(censoredInformationShare(a), censoredInformationShare(a + 0.25) - 1e-12) << a;

  const auto path = std::string(DSS_SOURCE_DIR) + "/config/sensors/thesis_sa.yaml";
  const CrlbCalculator thresholded(loadSensorConfig(path, {"optics.psf_node_step_deg=3"}));
  const Eigen::Matrix2d raw = thresholded.covariance(0.01, 0.01), read = thresholded.readoutCovariance(0.01, 0.01);
  ASSERT_TRUE(read.allFinite());
  EXPECT_GT(read(0, 0), 1.5 * raw(0, 0));
  std::printf("thesis_sa bound at (0.57, 0.57) deg: raw %.6f deg, 90%% threshold %.6f deg\n",
              std::sqrt(raw(0, 0)) * 180 / 3.14159265358979323846, std::sqrt(read(0, 0)) * 180 / 3.14159265358979323846);
  const CrlbCalculator plain(loadSensorConfig(path, {"optics.psf_node_step_deg=3", "threshold.enabled=false"}));
  EXPECT_EQ(plain.covariance(0.01, 0.01), plain.readoutCovariance(0.01, 0.01));
}

// The bound of a built unit is the one of its own geometry (dss eval
// --crlb-sensor unit): a unit whose mask sits 0.4 mm higher has the bound of a
// design that high, its detector's fixed patterns count only through the noise
// law, and the design drawn without errors keeps the design's bound.
TEST(Crlb, BuiltUnitHasTheBoundOfItsGeometry) {
  const auto path = std::string(DSS_SOURCE_DIR) + "/config/sensors/thesis_sa.yaml";
  const SensorConfig design = loadSensorConfig(path, {"optics.psf_node_step_deg=3"});
  const Eigen::Matrix2d nominal = CrlbCalculator(design).readoutCovariance(0.01, 0.01);
  EXPECT_EQ(CrlbCalculator(SensorInstance::nominalOf(design)).readoutCovariance(0.01, 0.01), nominal);

  SensorInstance unit = SensorInstance::nominalOf(design);
  unit.mask_offset_um.z() = 400.0;
  const Eigen::Matrix2d built = CrlbCalculator(unit).readoutCovariance(0.01, 0.01);
  const std::string height = "mask.height_mm=" + std::to_string(design.mask.height_mm + 0.4);
  const Eigen::Matrix2d higher =
      CrlbCalculator(loadSensorConfig(path, {"optics.psf_node_step_deg=3", height})).readoutCovariance(0.01, 0.01);
  ASSERT_TRUE(built.allFinite());
  EXPECT_LT(built(0, 0), 0.95 * nominal(0, 0));  // the spot moves further per degree
  EXPECT_NEAR(built(0, 0) / higher(0, 0), 1.0, 0.02);
  EXPECT_NEAR(built(1, 1) / higher(1, 1), 1.0, 0.02);

  unit.prnu_gain.assign(static_cast<std::size_t>(design.detector.width_px) * design.detector.height_px, 1.5f);
  EXPECT_EQ(CrlbCalculator(unit).readoutCovariance(0.01, 0.01), built);
}

}  // namespace
}  // namespace dss
