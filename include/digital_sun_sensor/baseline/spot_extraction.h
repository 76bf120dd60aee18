// Spot extraction, the first stage of the conventional baseline: threshold,
// connected components, sub-pixel centroid, outlier rejection.
#pragma once

#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "digital_sun_sensor/sim/sensor_config.h"

namespace dss {

enum class CentroidMethod {
  kCentreOfGravity,  // unweighted mean of the component's pixels
  kWeighted,         // intensity-weighted, local background subtracted
  kGaussianFit,      // pixel-integrated 2D Gaussian, shifted-Poisson MLE
};
CentroidMethod parseCentroidMethod(const std::string& text);  // throws std::invalid_argument
std::string toString(CentroidMethod method);

struct SpotExtractionConfig {
  CentroidMethod method = CentroidMethod::kWeighted;
  double threshold_dn = 0.0;        // absolute: a pixel belongs to a spot when DN > this
  double relative_threshold = 0.1;  // and DN - background > this x (peak - background)
  int min_area_px = 5;              // smaller components are hot pixels or noise
  double min_area_fraction = 0.1;   // of the largest component: debris fragments, ghosts
  double read_noise_dn = 0.1;       // for the Gaussian fit's noise model
  double electrons_per_dn = 32.0;
  // Hot pixels inside or beside a spot are repaired first (common/spike_filter.h):
  // margins from spikeMargins(sensor, spike_sigmas), empty when off.
  double spike_sigmas = 0.0;
  std::vector<int> spike_margin_dn;

  // Threshold at the sensor's noise floor (or any nonzero pixel when it
  // thresholds on chip), noise terms from the config.
  static SpotExtractionConfig forSensor(const SensorConfig& config);
};

struct DetectedSpot {
  double x_px = 0.0;  // from the detector centre, +x along columns
  double y_px = 0.0;  // from the detector centre, +y along rows
  int area_px = 0;
  double flux_dn = 0.0;  // background-subtracted sum
  double peak_dn = 0.0;
  double background_dn = 0.0;
  bool touches_edge = false;  // cut by the detector edge: biased centroid, presence only
};

// Accepted spots, brightest first; those cut by the detector edge are kept
// and flagged. `image`: CV_8U or CV_16U, one channel.
std::vector<DetectedSpot> extractSpots(const cv::Mat& image, const SpotExtractionConfig& config);

}  // namespace dss
