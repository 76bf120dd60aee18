#include "digital_sun_sensor/estimate/screened_estimator.h"

#include <cmath>
#include <stdexcept>

#include "digital_sun_sensor/model/input_spec.h"

namespace dss {

void ScreenOptions::validate() const {
  if (!(max_saturated_fraction > 0.0 && max_saturated_fraction <= 1.0))
    throw std::invalid_argument("max_saturated_fraction must be in (0, 1]");
  if (!(max_sigma_deg > 0.0)) throw std::invalid_argument("max_sigma_deg must be > 0");
  if (!(fov_margin_deg >= 0.0)) throw std::invalid_argument("fov_margin_deg must be >= 0");
  if (min_spot_px < 0) throw std::invalid_argument("min_spot_px must be >= 0");
}

cv::Mat removeSmallSpots(const cv::Mat& image, double threshold_dn, double floor_dn, int min_px) {
  if (min_px <= 1 || image.empty() || image.channels() != 1) return image;
  // Union-find over the lit pixels only (a few hundred in a sun sensor
  // image): about ten times cheaper than labelling the whole detector.
  std::vector<cv::Point> lit;
  cv::findNonZero(image > threshold_dn, lit);  // row-major order
  if (lit.empty()) return image;
  cv::Mat index(image.size(), CV_32S, cv::Scalar(-1));
  for (int i = 0; i < static_cast<int>(lit.size()); ++i) index.at<int>(lit[i]) = i;
  std::vector<int> parent(lit.size());
  for (std::size_t i = 0; i < parent.size(); ++i) parent[i] = static_cast<int>(i);
  auto root = [&](int i) {
    while (parent[i] != i) i = parent[i] = parent[parent[i]];
    return i;
  };
  for (int i = 0; i < static_cast<int>(lit.size()); ++i) {
    const cv::Point p = lit[i];
    // The 8-neighbours already visited in row-major order.
    for (const cv::Point d : {cv::Point(-1, -1), cv::Point(0, -1), cv::Point(1, -1), cv::Point(-1, 0)}) {
      const cv::Point q = p + d;
      if (q.x < 0 || q.y < 0 || q.x >= image.cols) continue;
      const int j = index.at<int>(q);
      if (j >= 0) parent[root(i)] = root(j);
    }
  }
  std::vector<int> size(lit.size(), 0);
  for (int i = 0; i < static_cast<int>(lit.size()); ++i) ++size[root(i)];
  cv::Mat cleaned;
  for (int i = 0; i < static_cast<int>(lit.size()); ++i) {
    if (size[root(i)] >= min_px) continue;
    if (cleaned.empty()) cleaned = image.clone();
    if (cleaned.depth() == CV_8U) {
      cleaned.at<std::uint8_t>(lit[i]) = cv::saturate_cast<std::uint8_t>(floor_dn);
    } else {
      cleaned.at<std::uint16_t>(lit[i]) = cv::saturate_cast<std::uint16_t>(floor_dn);
    }
  }
  return cleaned.empty() ? image : cleaned;
}

std::string screenImage(const cv::Mat& image, int max_code, const ScreenOptions& options) {
  if (image.empty() || image.channels() != 1) return "";  // the estimator names what is wrong
  const double saturated = cv::countNonZero(image >= max_code);
  return saturated > options.max_saturated_fraction * image.total() ? "saturated" : "";
}

void screenEstimate(SunEstimate* estimate, const SensorConfig& sensor, const ScreenOptions& options) {
  if (!estimate->valid) return;
  constexpr double kDeg = M_PI / 180.0;
  const double max_var = std::pow(options.max_sigma_deg * kDeg, 2);
  const double var_a = estimate->covariance[0], var_b = estimate->covariance[3];
  if (!std::isfinite(estimate->alpha_rad) || !std::isfinite(estimate->beta_rad)) {
    estimate->valid = false;
    estimate->status = "not_finite";
  } else if (!(var_a <= max_var && var_b <= max_var)) {  // also catches NaN
    estimate->valid = false;
    estimate->status = "out_of_distribution";
  } else if (std::abs(estimate->alpha_rad) > (sensor.fov.alpha_max_deg + options.fov_margin_deg) * kDeg ||
             std::abs(estimate->beta_rad) > (sensor.fov.beta_max_deg + options.fov_margin_deg) * kDeg) {
    estimate->valid = false;
    estimate->status = "outside_fov";
  }
}

ScreenedEstimator::ScreenedEstimator(std::unique_ptr<SunEstimator> inner, ScreenOptions options)
    : inner_(std::move(inner)), options_(options) {
  if (!inner_) throw std::invalid_argument("ScreenedEstimator: no estimator");
  options_.validate();
  const InputSpec spec = inputSpecFor(inner_->sensor());
  max_code_ = spec.max_code;
  threshold_dn_ = spec.threshold_dn;
  black_level_dn_ = spec.black_level_dn;
}

std::vector<SunEstimate> ScreenedEstimator::estimate(const std::vector<cv::Mat>& images) {
  std::vector<SunEstimate> out(images.size());
  std::vector<cv::Mat> passed;
  std::vector<std::size_t> where;
  for (std::size_t i = 0; i < images.size(); ++i) {
    // Hot pixels go first: they would also count as saturated pixels.
    const cv::Mat cleaned = removeSmallSpots(images[i], threshold_dn_, black_level_dn_, options_.min_spot_px);
    out[i].status = screenImage(cleaned, max_code_, options_);
    if (out[i].status.empty()) {
      passed.push_back(cleaned);
      where.push_back(i);
    }
  }
  if (passed.empty()) return out;
  std::vector<SunEstimate> estimates = inner_->estimate(passed);
  for (std::size_t k = 0; k < estimates.size(); ++k) {
    screenEstimate(&estimates[k], inner_->sensor(), options_);
    out[where[k]] = std::move(estimates[k]);
  }
  return out;
}

}  // namespace dss
