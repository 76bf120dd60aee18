// The light pattern of a mask whose spots merge (a coded mask of
// overlapping apertures under a threshold, e.g. thesis_ca): no spot can be
// told apart, but the whole pattern moves with the sun as one piece. The
// template is the design's own noise-free irradiance at normal incidence,
// rendered by the simulator's optics on a detector large enough to hold
// every spot and the field's whole shift, normalised to a peak of 1, and
// read anywhere by bicubic (Catmull-Rom) interpolation with its gradient.
#pragma once

#include <opencv2/core.hpp>

#include "digital_sun_sensor/sim/sensor_config.h"

namespace dss {

class PatternTemplate {
 public:
  // Renders the design of `config` (as drawn: no as-built errors, no
  // anomalies). Throws std::invalid_argument when the template would exceed
  // the detector size limit.
  explicit PatternTemplate(const SensorConfig& config);

  // Value at (x, y) um from the pattern's centre (the detector centre at
  // normal incidence) and, when not null, its gradient [1/um]. Outside the
  // rendered area: 0.
  double at(double x_um, double y_um, double* grad_x = nullptr, double* grad_y = nullptr) const;

  int sidePx() const { return side_px_; }
  double pitchUm() const { return pitch_um_; }
  const cv::Mat& values() const { return values_; }  // CV_64F, side x side

 private:
  cv::Mat values_;
  int side_px_ = 0;
  double pitch_um_ = 1.0;
  double centre_px_ = 0.0;
};

}  // namespace dss
