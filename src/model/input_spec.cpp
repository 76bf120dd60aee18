#include "digital_sun_sensor/model/input_spec.h"

#include <cmath>
#include <stdexcept>
#include <string>

#include "digital_sun_sensor/common/estimate_status.h"

namespace dss {

std::string InputSpec::badImageStatus(const cv::Mat& image) const {
  try {
    checkImage(image);
  } catch (const std::invalid_argument& ex) {
    return status::withDetail(status::kBadImage, ex.what());
  }
  return {};
}

void InputSpec::checkImage(const cv::Mat& image) const {
  if (image.empty()) throw std::invalid_argument("empty image");
  if (image.channels() != 1 || (image.depth() != CV_8U && image.depth() != CV_16U))
    throw std::invalid_argument("image must be single-channel 8- or 16-bit (mono8/mono16)");
  if (image.cols != width_px || image.rows != height_px)
    throw std::invalid_argument("image is " + std::to_string(image.cols) + "x" + std::to_string(image.rows) +
                                " px but the sensor has " + std::to_string(width_px) + "x" + std::to_string(height_px));
}

InputSpec inputSpecFor(const SensorConfig& config, double noise_sigmas) {
  InputSpec spec;
  spec.width_px = config.detector.width_px;
  spec.height_px = config.detector.height_px;
  spec.max_code = config.maxCode();
  if (config.threshold.enabled && config.threshold.rescale) {
    spec.black_level_dn = 0.0;
    spec.threshold_dn = 0.0;
  } else if (config.threshold.enabled) {
    spec.black_level_dn = config.noise.black_level_dn;
    spec.threshold_dn = std::floor(config.threshold.level_fraction * spec.max_code) - 1.0;
  } else {
    const auto& n = config.noise;
    const double gain_dn_per_e = spec.max_code / n.adc_full_scale_e;
    const double dark_e = n.darkCurrentAtTemperatureEPerS() * config.exposure.exposure_s;
    const double sigma_dn = std::sqrt(n.read_noise_e * n.read_noise_e + dark_e) * gain_dn_per_e;
    spec.black_level_dn = n.black_level_dn;
    spec.threshold_dn =
        std::round(n.black_level_dn + dark_e * gain_dn_per_e) + std::max(1.0, std::ceil(noise_sigmas * sigma_dn));
  }
  return spec;
}

std::vector<ActivePixel> pixelsAboveThreshold(const cv::Mat& image, const InputSpec& spec) {
  std::vector<ActivePixel> pixels;
  for (int y = 0; y < image.rows; ++y) {
    if (image.depth() == CV_8U) {
      const auto* row = image.ptr<std::uint8_t>(y);
      for (int x = 0; x < image.cols; ++x)
        if (row[x] > spec.threshold_dn) pixels.push_back({y, x, row[x]});
    } else {
      const auto* row = image.ptr<std::uint16_t>(y);
      for (int x = 0; x < image.cols; ++x)
        if (row[x] > spec.threshold_dn) pixels.push_back({y, x, row[x]});
    }
  }
  return pixels;
}

}  // namespace dss
