#include "digital_sun_sensor/eval/crlb.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>

#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/sim/geometry.h"

namespace dss {

double censoredInformationShare(double a) {
  if (!std::isfinite(a)) return a < 0 ? 1.0 : 0.0;
  const double phi = std::exp(-0.5 * a * a) / std::sqrt(2.0 * kPi);
  const double cdf = 0.5 * std::erfc(-a / std::sqrt(2.0));
  return std::max(0.0, 1.0 - cdf + a * phi + (cdf > 1e-300 ? phi * phi / cdf : 0.0));
}

Eigen::MatrixXd fisherInformation(const cv::Mat& mean, const std::vector<cv::Mat>& derivatives,
                                  const std::function<double(double)>& variance, double max_mean, double censor_below) {
  const int n = static_cast<int>(derivatives.size());
  cv::Mat m64;
  mean.convertTo(m64, CV_64F);
  std::vector<cv::Mat> d64(n);
  for (int k = 0; k < n; ++k) {
    CV_Assert(derivatives[k].size() == mean.size());
    derivatives[k].convertTo(d64[k], CV_64F);
  }
  Eigen::MatrixXd fisher = Eigen::MatrixXd::Zero(n, n);
  Eigen::VectorXd g(n);
  for (int r = 0; r < m64.rows; ++r) {
    const double* mu = m64.ptr<double>(r);
    for (int c = 0; c < m64.cols; ++c) {
      if (mu[c] >= max_mean) continue;
      bool any = false;
      for (int k = 0; k < n; ++k) {
        g[k] = d64[k].ptr<double>(r)[c];
        any |= g[k] != 0.0;
      }
      if (!any) continue;
      const double v = variance(mu[c]);
      if (!(v > 0.0)) continue;
      const double share = censoredInformationShare((censor_below - mu[c]) / std::sqrt(v));
      if (share > 0.0) fisher.noalias() += g * g.transpose() * (share / v);
    }
  }
  return fisher;
}

CrlbCalculator::CrlbCalculator(const SensorConfig& config) : CrlbCalculator(SensorInstance::nominalOf(config)) {}

CrlbCalculator::CrlbCalculator(const SensorInstance& unit) : noise_(unit.config) {
  SensorInstance geometry = unit;
  geometry.prnu_gain.clear();
  geometry.dark_scale.clear();
  geometry.hot_pixels.clear();
  renderer_ = std::make_unique<Renderer>(geometry);
  const SensorConfig& config = unit.config;
  const auto& n = config.noise;
  const double step_e = n.adc_full_scale_e / config.maxCode();
  dark_e_per_s_ = n.darkCurrentAtTemperatureEPerS();
  if (config.threshold.enabled) {
    // Codes below the level read 0; code d holds signals from (d - 0.5 - black) / gain.
    const double level_code = std::ceil(config.threshold.level_fraction * config.maxCode());
    threshold_e_ = (level_code - 0.5 - n.black_level_dn) * step_e;
  }
}

CrlbCalculator::~CrlbCalculator() = default;

double CrlbCalculator::pixelVariance(double mean_e) const { return noise_.varianceE2(mean_e); }

Eigen::Matrix2d CrlbCalculator::covariance(double alpha_rad, double beta_rad) const {
  return bound(alpha_rad, beta_rad, false);
}

Eigen::Matrix2d CrlbCalculator::readoutCovariance(double alpha_rad, double beta_rad) const {
  return bound(alpha_rad, beta_rad, true);
}

Eigen::Matrix2d CrlbCalculator::bound(double alpha_rad, double beta_rad, bool censored) const {
  const SensorConfig& config = renderer_->config();
  ImageTruth truth;
  const cv::Mat mean = renderer_->expectedElectrons(sunVectorFromAngles(alpha_rad, beta_rad), &truth);
  const double exposure_s = truth.exposure_s;
  // ~0.03 px of spot motion at h = 5 mm: well inside the linear range.
  constexpr double kStepRad = 1e-5;
  std::vector<cv::Mat> derivatives;
  for (int axis = 0; axis < 2; ++axis) {
    cv::Mat side[2];
    for (int sign = 0; sign < 2; ++sign) {
      const double d = sign == 0 ? kStepRad : -kStepRad;
      ImageTruth t;
      side[sign] = renderer_->expectedElectrons(
          sunVectorFromAngles(alpha_rad + (axis == 0 ? d : 0.0), beta_rad + (axis == 1 ? d : 0.0)), &t);
      // Hold the exposure: the derivative is of the scene, not of the auto-exposure loop.
      if (t.exposure_s > 0.0) side[sign] *= exposure_s / t.exposure_s;
    }
    derivatives.push_back((side[0] - side[1]) / (2.0 * kStepRad));
  }
  const double dark_e = dark_e_per_s_ * exposure_s;
  const Eigen::MatrixXd fisher = fisherInformation(
      mean, derivatives, [&](double mu) { return pixelVariance(mu) + dark_e; }, config.noise.full_well_e,
      censored ? threshold_e_ - dark_e : -std::numeric_limits<double>::infinity());
  const Eigen::Matrix2d f = fisher;
  if (!(f.determinant() > 0.0)) return Eigen::Matrix2d::Constant(std::numeric_limits<double>::infinity());
  return f.inverse();
}

}  // namespace dss
