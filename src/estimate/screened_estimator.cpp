#include "digital_sun_sensor/estimate/screened_estimator.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "digital_sun_sensor/common/estimate_status.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/model/input_spec.h"

namespace dss {

void ScreenOptions::validate() const {
  if (!(max_saturated_fraction > 0.0 && max_saturated_fraction <= 1.0))
    throw std::invalid_argument("max_saturated_fraction must be in (0, 1]");
  if (!(max_sigma_deg > 0.0)) throw std::invalid_argument("max_sigma_deg must be > 0");
  if (!(fov_margin_deg >= 0.0)) throw std::invalid_argument("fov_margin_deg must be >= 0");
  if (min_spot_px < 0) throw std::invalid_argument("min_spot_px must be >= 0");
  if (!(spike_sigmas >= 0.0 && std::isfinite(spike_sigmas)))
    throw std::invalid_argument("spike_sigmas must be >= 0 and finite");
}

namespace {

struct Cleaned {
  cv::Mat image;                 // without small lit groups (the input itself when it had none)
  std::size_t saturated_px = 0;  // pixels at or above the top code in it
};

// One scan of the image: its lit pixels, the groups (8-connected, union-find
// over the lit pixels only) smaller than `min_px` set to `floor_dn`, and the
// saturated pixels counted among those kept. The neighbours above are found
// by walking the row above's lit pixels alongside (linear: a merged-spot
// image such as thesis_ca's lights ~40 000 pixels).
Cleaned clean(const cv::Mat& image, double threshold_dn, double floor_dn, int min_px, int max_code) {
  InputSpec spec;
  spec.threshold_dn = threshold_dn;
  const std::vector<ActivePixel> lit = pixelsAboveThreshold(image, spec);  // row-major
  const int n = static_cast<int>(lit.size());
  std::vector<int> parent(lit.size());
  for (int i = 0; i < n; ++i) parent[i] = i;
  auto root = [&](int i) {
    while (parent[i] != i) i = parent[i] = parent[parent[i]];
    return i;
  };
  if (min_px > 1) {
    // [above, above_end): the lit pixels of row y - 1 from the first that can touch pixel i.
    int row_begin = 0, above = 0, above_end = 0;
    for (int i = 0; i < n; ++i) {
      const int y = lit[i].y, x = lit[i].x;
      if (i == 0 || lit[i - 1].y != y) {  // a new row: the previous one lies above it if it is y - 1
        const bool touching = i > 0 && lit[i - 1].y == y - 1;
        above = touching ? row_begin : i;
        above_end = i;
        row_begin = i;
      }
      if (i > row_begin && lit[i - 1].x == x - 1) parent[root(i)] = root(i - 1);
      while (above < above_end && lit[above].x < x - 1) ++above;
      for (int j = above; j < above_end && lit[j].x <= x + 1; ++j) parent[root(i)] = root(j);
    }
  }
  std::vector<int> size(lit.size(), 0);
  for (int i = 0; i < static_cast<int>(lit.size()); ++i) ++size[root(i)];
  Cleaned out{image, 0};
  for (int i = 0; i < static_cast<int>(lit.size()); ++i) {
    if (min_px <= 1 || size[root(i)] >= min_px) {
      out.saturated_px += lit[i].dn >= max_code;
      continue;
    }
    if (out.image.data == image.data) out.image = image.clone();
    if (image.depth() == CV_8U) {
      out.image.at<std::uint8_t>(lit[i].y, lit[i].x) = cv::saturate_cast<std::uint8_t>(floor_dn);
    } else {
      out.image.at<std::uint16_t>(lit[i].y, lit[i].x) = cv::saturate_cast<std::uint16_t>(floor_dn);
    }
  }
  // A top code at or under the threshold (never for the shipped sensors) is not among the lit pixels.
  if (threshold_dn >= max_code) out.saturated_px = cv::countNonZero(out.image >= max_code);
  return out;
}

std::string saturationStatus(std::size_t saturated_px, std::size_t total_px, const ScreenOptions& options) {
  return saturated_px > options.max_saturated_fraction * total_px ? status::kSaturated : "";
}

}  // namespace

cv::Mat removeSmallSpots(const cv::Mat& image, double threshold_dn, double floor_dn, int min_px) {
  if (min_px <= 1 || image.empty() || image.channels() != 1) return image;
  return clean(image, threshold_dn, floor_dn, min_px, std::numeric_limits<int>::max()).image;
}

std::string screenImage(const cv::Mat& image, int max_code, const ScreenOptions& options) {
  if (image.empty() || image.channels() != 1) return "";  // the estimator names what is wrong
  return saturationStatus(cv::countNonZero(image >= max_code), image.total(), options);
}

void screenEstimate(SunEstimate* estimate, const SensorConfig& sensor, const ScreenOptions& options) {
  if (!estimate->valid) return;
  const double max_var = std::pow(options.max_sigma_deg * kRadPerDeg, 2);
  // The image's own variance: the model's shared part says nothing of the image.
  const double var_a = estimate->covariance[0] - std::pow(estimate->model_sigma_rad[0], 2);
  const double var_b = estimate->covariance[3] - std::pow(estimate->model_sigma_rad[1], 2);
  if (!std::isfinite(estimate->alpha_rad) || !std::isfinite(estimate->beta_rad)) {
    estimate->valid = false;
    estimate->status = status::kNotFinite;
  } else if (!(var_a <= max_var && var_b <= max_var)) {  // also catches NaN
    estimate->valid = false;
    estimate->status = status::kOutOfDistribution;
  } else if (std::abs(estimate->alpha_rad) > (sensor.fov.alpha_max_deg + options.fov_margin_deg) * kRadPerDeg ||
             std::abs(estimate->beta_rad) > (sensor.fov.beta_max_deg + options.fov_margin_deg) * kRadPerDeg) {
    estimate->valid = false;
    estimate->status = status::kOutsideFov;
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
  spike_margin_dn_ = spikeMargins(inner_->sensor(), options_.spike_sigmas);
}

cv::Mat ScreenedEstimator::screenedImage(const cv::Mat& image) const {
  if (image.empty() || image.channels() != 1 || (image.depth() != CV_8U && image.depth() != CV_16U)) return image;
  return clean(repairSpikes(image, spike_margin_dn_), threshold_dn_, black_level_dn_, options_.min_spot_px, max_code_)
      .image;
}

std::vector<SunEstimate> ScreenedEstimator::estimate(const std::vector<cv::Mat>& images) {
  return screenAndEstimate(images, [&](const std::vector<cv::Mat>& passed, const std::vector<std::size_t>&) {
    return inner_->estimate(passed);
  });
}

std::vector<SunEstimate> ScreenedEstimator::estimateWithSubFovHints(const std::vector<cv::Mat>& images,
                                                                    const std::vector<int>& subfov_classes) {
  if (subfov_classes.size() != images.size())
    throw std::invalid_argument(std::to_string(subfov_classes.size()) + " sub-FOV hints for " +
                                std::to_string(images.size()) + " images");
  return screenAndEstimate(images, [&](const std::vector<cv::Mat>& passed, const std::vector<std::size_t>& where) {
    std::vector<int> passed_hints;
    for (std::size_t i : where) passed_hints.push_back(subfov_classes[i]);
    return inner_->estimateWithSubFovHints(passed, passed_hints);
  });
}

std::vector<SunEstimate> ScreenedEstimator::estimateWithCoarseDirections(const std::vector<cv::Mat>& images,
                                                                         const CoarseDirections& coarse) {
  if (coarse.size() != images.size())
    throw std::invalid_argument(std::to_string(coarse.size()) + " coarse directions for " +
                                std::to_string(images.size()) + " images");
  return screenAndEstimate(images, [&](const std::vector<cv::Mat>& passed, const std::vector<std::size_t>& where) {
    CoarseDirections passed_coarse;
    for (std::size_t i : where) passed_coarse.push_back(coarse[i]);
    return inner_->estimateWithCoarseDirections(passed, passed_coarse);
  });
}

std::vector<SunEstimate> ScreenedEstimator::screenAndEstimate(const std::vector<cv::Mat>& images, const Run& run) {
  std::vector<SunEstimate> out(images.size());
  std::vector<cv::Mat> passed;
  std::vector<std::size_t> where;
  for (std::size_t i = 0; i < images.size(); ++i) {
    const cv::Mat& image = images[i];
    if (image.empty() || image.channels() != 1 || (image.depth() != CV_8U && image.depth() != CV_16U)) {
      passed.push_back(image);  // the estimator names what is wrong
      where.push_back(i);
      continue;
    }
    // Hot pixels go first (spikes, then small groups): they would also count as saturated pixels.
    const Cleaned cleaned =
        clean(repairSpikes(image, spike_margin_dn_), threshold_dn_, black_level_dn_, options_.min_spot_px, max_code_);
    out[i].status = saturationStatus(cleaned.saturated_px, image.total(), options_);
    if (out[i].status.empty()) {
      passed.push_back(cleaned.image);
      where.push_back(i);
    }
  }
  if (passed.empty()) return out;
  std::vector<SunEstimate> estimates = run(passed, where);
  for (std::size_t k = 0; k < estimates.size(); ++k) {
    screenEstimate(&estimates[k], inner_->sensor(), options_);
    out[where[k]] = std::move(estimates[k]);
  }
  return out;
}

}  // namespace dss
