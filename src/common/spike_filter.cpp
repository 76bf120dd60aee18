#include "digital_sun_sensor/common/spike_filter.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace dss {

std::vector<int> spikeMargins(const SensorConfig& sensor, double sigmas) {
  if (!std::isfinite(sigmas)) throw std::invalid_argument("spike_sigmas must be finite");
  if (sigmas <= 0.0) return {};
  const auto& n = sensor.noise;
  const int max_code = sensor.maxCode();
  const double gain_dn_per_e = max_code / n.adc_full_scale_e;
  const double level = sensor.threshold.enabled ? sensor.threshold.level_fraction * max_code : 0.0;
  // Output codes per raw code: the on-chip rescale stretches [level, top] onto [0, top].
  const double stretch = sensor.threshold.enabled && sensor.threshold.rescale ? max_code / (max_code - level) : 1.0;
  std::vector<int> margin(max_code + 1);
  for (int code = 0; code <= max_code; ++code) {
    const double raw_dn = stretch > 1.0 ? level + code / stretch : code;
    const double electrons = std::max(0.0, (raw_dn - n.black_level_dn) / gain_dn_per_e);
    const double var_e =
        (n.shot_noise ? electrons : 0.0) + n.read_noise_e * n.read_noise_e + std::pow(n.prnu_fraction * electrons, 2);
    const double sigma_out = std::sqrt(var_e * gain_dn_per_e * gain_dn_per_e + 1.0 / 12.0) * stretch;
    margin[code] = static_cast<int>(std::ceil(sigmas * std::sqrt(2.0) * sigma_out + kSpikePeakAllowance * code)) + 1;
  }
  return margin;
}

namespace {

template <typename T>
cv::Mat repair(const cv::Mat& image, const std::vector<int>& margin_dn, int* repaired) {
  const int rows = image.rows, cols = image.cols;
  // No pixel at or under the smallest margin can be a spike: most of an image is skipped at once.
  const int floor_dn = *std::min_element(margin_dn.begin(), margin_dn.end());
  const int last = static_cast<int>(margin_dn.size()) - 1;
  cv::Mat out;
  int count = 0;
  T neighbours[8];
  for (int r = 0; r < rows; ++r) {
    const T* row = image.ptr<T>(r);
    for (int c = 0; c < cols; ++c) {
      const int value = row[c];
      if (value <= floor_dn) continue;
      int k = 0;
      for (int dr = -1; dr <= 1; ++dr) {
        if (r + dr < 0 || r + dr >= rows) continue;
        const T* nrow = image.ptr<T>(r + dr);
        for (int dc = -1; dc <= 1; ++dc)
          if ((dr || dc) && c + dc >= 0 && c + dc < cols) neighbours[k++] = nrow[c + dc];
      }
      const int brightest = *std::max_element(neighbours, neighbours + k);
      if (value - brightest <= margin_dn[std::min(brightest, last)]) continue;
      if (out.empty()) out = image.clone();
      std::nth_element(neighbours, neighbours + (k - 1) / 2, neighbours + k);
      out.at<T>(r, c) = neighbours[(k - 1) / 2];  // read from the input: independent of scan order
      ++count;
    }
  }
  if (repaired) *repaired = count;
  return out.empty() ? image : out;
}

}  // namespace

cv::Mat repairSpikes(const cv::Mat& image, const std::vector<int>& margin_dn, int* repaired) {
  if (repaired) *repaired = 0;
  if (margin_dn.empty() || image.empty() || image.channels() != 1 || image.rows < 2 || image.cols < 2) return image;
  if (image.depth() == CV_8U) return repair<std::uint8_t>(image, margin_dn, repaired);
  if (image.depth() == CV_16U) return repair<std::uint16_t>(image, margin_dn, repaired);
  return image;
}

}  // namespace dss
