// What every sun estimator (SSCNN, centroid baseline) produces for one image,
// and the interface evaluation and the nodes drive them through.
#pragma once

#include <array>
#include <opencv2/core.hpp>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "digital_sun_sensor/sim/sensor_config.h"

namespace dss {

struct SunEstimate {
  double alpha_rad = 0.0;
  double beta_rad = 0.0;
  std::array<double, 4> covariance{};  // row-major 2x2 of (alpha, beta) [rad^2]
  int subfov_class = -1;
  bool valid = false;
  std::string status;  // empty when valid, else a short reason ("no_sun", ...)
  // Geometric-head models: the spots' residual against the model's geometry
  // over its calibrated level (Prediction::spot_mismatch; ~1 on the sensor
  // it was calibrated for); 0 where not measured.
  double spot_mismatch = 0.0;
  // Pattern estimator: the image's chi^2 excess over the design's image at
  // the answer (AliasEvidence::unexplained_z: light the design does not
  // hold); 0 where not measured.
  double unexplained_light_z = 0.0;
  // The part of the covariance's diagonal that every estimate of the model
  // shares, as a sigma per axis [rad]: its geometry's uncertainty (a unit
  // calibration's, or a family model's unit tolerances). What is left is
  // the image's own, which out_of_distribution judges.
  std::array<double, 2> model_sigma_rad{};
};

// A sun direction known coarsely from elsewhere (a coarse sun sensor, the
// attitude filter's prediction), with its 1-sigma error per axis.
struct CoarseDirection {
  double alpha_rad = 0.0, beta_rad = 0.0;
  double sigma_rad = 0.0;
};
using CoarseDirections = std::vector<std::optional<CoarseDirection>>;

class SunEstimator {
 public:
  virtual ~SunEstimator() = default;
  // "sscnn", "centroid": the SunAngles.source of its estimates.
  virtual std::string source() const = 0;
  // The sensor design it was fitted or trained for.
  virtual const SensorConfig& sensor() const = 0;
  // One estimate per image, in order. Images that cannot be used (wrong size
  // or encoding) give valid = false with the reason in status.
  virtual std::vector<SunEstimate> estimate(const std::vector<cv::Mat>& images) = 0;
  // The same with each image's sub-FOV class known from elsewhere (a coarse
  // sun sensor's quadrant; the published protocol gives it to its network),
  // for estimators whose sensor cannot tell it from the image alone. The
  // others throw std::invalid_argument.
  virtual std::vector<SunEstimate> estimateWithSubFovHints(const std::vector<cv::Mat>& images,
                                                           const std::vector<int>& subfov_classes) {
    (void)images;
    (void)subfov_classes;
    throw std::invalid_argument("the " + source() + " estimator takes no sub-FOV hint");
  }
  // The same with a coarse direction per image (none: the image alone). An
  // estimator whose sensor repeats its pattern within the field (thesis_ca:
  // 5.74 deg in alpha) lets it choose between two places the image fits
  // about equally; the others need none and ignore it.
  virtual std::vector<SunEstimate> estimateWithCoarseDirections(const std::vector<cv::Mat>& images,
                                                                const CoarseDirections& coarse) {
    (void)coarse;
    return estimate(images);
  }
  // Does now, on `threads` threads, the one-off work its first images would
  // otherwise pay for (the pattern head's diffraction cache of its design:
  // seconds); a no-op for the others.
  virtual void warmUp(int threads) const { (void)threads; }
};

}  // namespace dss
