// How a sensor image becomes the SSCNN's sparse input: which pixels are active
// sites and how their features (value, x, y) are scaled. Torch-free; stored in
// model-file metadata so that the estimator encodes exactly as in training.
#pragma once

#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "digital_sun_sensor/sim/sensor_config.h"

namespace dss {

struct InputSpec {
  int width_px = 512;
  int height_px = 512;
  int max_code = 255;           // top digital number
  double black_level_dn = 0.0;  // value feature = (DN - black) / (max_code - black)
  double threshold_dn = 0.0;    // a pixel is active when DN > threshold_dn
  int max_sites = 16384;        // per image; the brightest are kept beyond this

  // Throws std::invalid_argument naming what does not match.
  void checkImage(const cv::Mat& image) const;
  // The same as an estimate's status: "bad_image: <what>", or empty.
  std::string badImageStatus(const cv::Mat& image) const;
};

// A pixel that can be a site: above the spec's threshold.
struct ActivePixel {
  int y, x;
  int dn;
};

// Every pixel above spec.threshold_dn, in row-major order (no max_sites limit).
std::vector<ActivePixel> pixelsAboveThreshold(const cv::Mat& image, const InputSpec& spec);

// Threshold `noise_sigmas` read + dark noise standard deviations above the
// black level (at least 1 DN), or every nonzero pixel when the sensor
// thresholds on chip (everything below its level already reads 0).
InputSpec inputSpecFor(const SensorConfig& config, double noise_sigmas = 5.0);

}  // namespace dss
