#include "digital_sun_sensor/baseline/spot_extraction.h"

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

#include "digital_sun_sensor/baseline/gaussian_fit.h"
#include "digital_sun_sensor/common/spike_filter.h"
#include "digital_sun_sensor/model/input_spec.h"

namespace dss {
namespace {

// Median code of the whole image from its histogram (spots cover few pixels).
double medianCode(const cv::Mat& image, int max_code) {
  std::vector<int> histogram(max_code + 1, 0);
  for (int r = 0; r < image.rows; ++r) {
    if (image.depth() == CV_8U) {
      const auto* p = image.ptr<std::uint8_t>(r);
      for (int c = 0; c < image.cols; ++c) ++histogram[p[c]];
    } else {
      const auto* p = image.ptr<std::uint16_t>(r);
      for (int c = 0; c < image.cols; ++c) ++histogram[p[c]];
    }
  }
  const long half = static_cast<long>(image.total()) / 2;
  long seen = 0;
  for (int code = 0; code <= max_code; ++code) {
    seen += histogram[code];
    if (seen > half) return code;
  }
  return max_code;
}

// Median of the pixels on the rim of `box` grown by `margin` (inside the
// image) that belong to no component: the spot's local background.
double localBackground(const cv::Mat& values, const cv::Mat& labels, const cv::Rect& box, int margin) {
  const cv::Rect grown =
      (box + cv::Size(2 * margin, 2 * margin) - cv::Point(margin, margin)) & cv::Rect(0, 0, values.cols, values.rows);
  std::vector<double> rim;
  auto take = [&](int r, int c) {
    if (labels.at<int>(r, c) == 0) rim.push_back(values.at<double>(r, c));
  };
  for (int c = grown.x; c < grown.x + grown.width; ++c) {
    take(grown.y, c);
    take(grown.y + grown.height - 1, c);
  }
  for (int r = grown.y + 1; r < grown.y + grown.height - 1; ++r) {
    take(r, grown.x);
    take(r, grown.x + grown.width - 1);
  }
  if (rim.empty()) return 0.0;
  std::nth_element(rim.begin(), rim.begin() + rim.size() / 2, rim.end());
  return rim[rim.size() / 2];
}

}  // namespace

CentroidMethod parseCentroidMethod(const std::string& text) {
  if (text == "cog") return CentroidMethod::kCentreOfGravity;
  if (text == "weighted") return CentroidMethod::kWeighted;
  if (text == "gaussian") return CentroidMethod::kGaussianFit;
  throw std::invalid_argument("unknown centroid method '" + text + "' (expected cog, weighted or gaussian)");
}

std::string toString(CentroidMethod method) {
  switch (method) {
    case CentroidMethod::kCentreOfGravity:
      return "cog";
    case CentroidMethod::kWeighted:
      return "weighted";
    case CentroidMethod::kGaussianFit:
      return "gaussian";
  }
  return "weighted";
}

SpotExtractionConfig SpotExtractionConfig::forSensor(const SensorConfig& config) {
  SpotExtractionConfig out;
  // The SSCNN's input threshold is the same noise-floor rule.
  out.threshold_dn = inputSpecFor(config).threshold_dn;
  // On-chip thresholding already removed the background; otherwise stay
  // clear of stray-light gradients.
  out.relative_threshold = config.threshold.enabled ? 0.0 : 0.25;
  const auto& n = config.noise;
  out.electrons_per_dn = n.adc_full_scale_e / config.maxCode();
  out.read_noise_dn = n.read_noise_e / out.electrons_per_dn;
  out.spike_sigmas = kDefaultSpikeSigmas;
  out.spike_margin_dn = spikeMargins(config, out.spike_sigmas);
  return out;
}

std::vector<DetectedSpot> extractSpots(const cv::Mat& image, const SpotExtractionConfig& config) {
  if (image.empty() || image.channels() != 1 || (image.depth() != CV_8U && image.depth() != CV_16U))
    throw std::invalid_argument("spot extraction needs a non-empty single-channel 8- or 16-bit image");
  const int max_code = image.depth() == CV_8U ? 255 : 65535;
  cv::Mat values;
  repairSpikes(image, config.spike_margin_dn).convertTo(values, CV_64F);
  double peak = 0.0;
  cv::minMaxLoc(values, nullptr, &peak);
  const double background = medianCode(image, max_code);
  const double level = std::max(config.threshold_dn, background + config.relative_threshold * (peak - background));

  cv::Mat mask = values > level, labels, box_stats, centroids;
  const int count = cv::connectedComponentsWithStats(mask, labels, box_stats, centroids, 8, CV_32S);

  std::vector<DetectedSpot> candidates;
  const double half_w = 0.5 * (image.cols - 1), half_h = 0.5 * (image.rows - 1);
  for (int k = 1; k < count; ++k) {
    const int area = box_stats.at<int>(k, cv::CC_STAT_AREA);
    if (area < config.min_area_px) continue;
    const cv::Rect box(box_stats.at<int>(k, cv::CC_STAT_LEFT), box_stats.at<int>(k, cv::CC_STAT_TOP),
                       box_stats.at<int>(k, cv::CC_STAT_WIDTH), box_stats.at<int>(k, cv::CC_STAT_HEIGHT));
    DetectedSpot spot;
    spot.area_px = area;
    spot.touches_edge = box.x == 0 || box.y == 0 || box.x + box.width == image.cols || box.y + box.height == image.rows;
    spot.background_dn = config.relative_threshold > 0.0 ? localBackground(values, labels, box, 3) : 0.0;
    double sum_w = 0.0, sum_x = 0.0, sum_y = 0.0, sum_x1 = 0.0, sum_y1 = 0.0;
    for (int r = box.y; r < box.y + box.height; ++r) {
      const int* lab = labels.ptr<int>(r);
      const double* val = values.ptr<double>(r);
      for (int c = box.x; c < box.x + box.width; ++c) {
        if (lab[c] != k) continue;
        const double w = std::max(0.0, val[c] - spot.background_dn);
        sum_w += w;
        sum_x += w * c;
        sum_y += w * r;
        sum_x1 += c;
        sum_y1 += r;
        spot.peak_dn = std::max(spot.peak_dn, val[c]);
      }
    }
    spot.flux_dn = sum_w;
    double cx = sum_x1 / area, cy = sum_y1 / area;
    if (config.method != CentroidMethod::kCentreOfGravity && sum_w > 0.0) cx = sum_x / sum_w, cy = sum_y / sum_w;
    if (config.method == CentroidMethod::kGaussianFit && sum_w > 0.0) {
      const cv::Rect patch = (box + cv::Size(6, 6) - cv::Point(3, 3)) & cv::Rect(0, 0, image.cols, image.rows);
      cv::Mat counts = (values(patch) - spot.background_dn) * config.electrons_per_dn;
      GaussianSpot start{cx - patch.x, cy - patch.y, std::max(0.5, 0.5 * std::sqrt(area / M_PI)),
                         sum_w * config.electrons_per_dn, 0.0};
      GaussianFitOptions options;
      options.read_noise = config.read_noise_dn * config.electrons_per_dn;
      const GaussianFitResult fit = fitGaussianSpot(counts, start, options);
      if (fit.converged && std::abs(fit.spot.x - start.x) < box.width && std::abs(fit.spot.y - start.y) < box.height) {
        cx = fit.spot.x + patch.x;
        cy = fit.spot.y + patch.y;
      }
    }
    spot.x_px = cx - half_w;
    spot.y_px = cy - half_h;
    candidates.push_back(spot);
  }

  int largest = 0;
  for (const auto& c : candidates) largest = std::max(largest, c.area_px);
  std::vector<DetectedSpot> spots;
  for (const auto& c : candidates)
    if (c.area_px >= config.min_area_fraction * largest) spots.push_back(c);
  std::sort(spots.begin(), spots.end(),
            [](const DetectedSpot& a, const DetectedSpot& b) { return a.flux_dn > b.flux_dn; });
  return spots;
}

}  // namespace dss
