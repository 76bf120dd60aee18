// Cramer-Rao lower bound on the sun angles. Fisher information of the angles
// from the noise-free expected image mu(theta) and the detector noise:
//   I = sum_k (d mu_k / d theta)(d mu_k / d theta)^T / var_k,
// var_k = mu_k (shot) + dark + read^2 + step^2 / 12 (quantisation) + (PRNU mu_k)^2,
// which is exact for pure Poisson data and the usual Gaussian approximation
// otherwise. Saturated pixels (mu >= full well) carry no information and are
// left out. covariance() is the bound of the raw readout; readoutCovariance()
// that of the readout as configured: an on-chip threshold censors every pixel
// below it to 0, and a censored Gaussian pixel (Tobit model) keeps the share
//   w(a) = 1 - Phi(a) + a phi(a) + phi(a)^2 / Phi(a),  a = (T - mu) / sigma,
// of its information (w -> 1 far above T, -> 0 far below).
#pragma once

#include <Eigen/Core>
#include <functional>
#include <limits>
#include <memory>
#include <opencv2/core.hpp>
#include <vector>

#include "digital_sun_sensor/sim/pixel_noise.h"
#include "digital_sun_sensor/sim/renderer.h"

namespace dss {

// Fisher information from a mean image and its derivatives (CV_32F or CV_64F,
// same size) with a per-pixel variance law; pixels with mean >= `max_mean`
// are skipped; values below `censor_below` read as one value (threshold).
Eigen::MatrixXd fisherInformation(const cv::Mat& mean, const std::vector<cv::Mat>& derivatives,
                                  const std::function<double(double)>& variance,
                                  double max_mean = std::numeric_limits<double>::infinity(),
                                  double censor_below = -std::numeric_limits<double>::infinity());

// The Tobit information share w(a) above (1 for a = -inf).
double censoredInformationShare(double a);

class CrlbCalculator {
 public:
  // The nominal sensor of `config` without per-image anomalies.
  explicit CrlbCalculator(const SensorConfig& config);
  // One drawn sensor (a built unit): its mask pose and apertures as built,
  // its detector uniform (fixed patterns are in the noise law's PRNU term).
  explicit CrlbCalculator(const SensorInstance& unit);
  ~CrlbCalculator();

  // Bound on the covariance of (alpha, beta) [rad^2] at a sun direction;
  // infinite when the image holds no usable signal.
  Eigen::Matrix2d covariance(double alpha_rad, double beta_rad) const;
  // The same for the readout as configured (on-chip threshold); equal to
  // covariance() for a sensor without one.
  Eigen::Matrix2d readoutCovariance(double alpha_rad, double beta_rad) const;

  // Per-pixel variance [e^2] for a mean signal [e].
  double pixelVariance(double mean_e) const;

 private:
  std::unique_ptr<Renderer> renderer_;
  PixelNoise noise_;  // without dark current: that depends on the exposure
  double dark_e_per_s_ = 0.0;
  double threshold_e_ = -std::numeric_limits<double>::infinity();  // lowest kept signal, before dark current

  Eigen::Matrix2d bound(double alpha_rad, double beta_rad, bool censored) const;
};

}  // namespace dss
