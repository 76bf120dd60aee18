#include "digital_sun_sensor/baseline/pattern_template.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "digital_sun_sensor/common/limits.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/sim/renderer.h"

namespace dss {
namespace {

// Catmull-Rom weights and their derivatives at fraction t.
void cubicWeights(double t, double w[4], double d[4]) {
  const double t2 = t * t, t3 = t2 * t;
  w[0] = -0.5 * t3 + t2 - 0.5 * t;
  w[1] = 1.5 * t3 - 2.5 * t2 + 1.0;
  w[2] = -1.5 * t3 + 2.0 * t2 + 0.5 * t;
  w[3] = 0.5 * t3 - 0.5 * t2;
  d[0] = -1.5 * t2 + 2.0 * t - 0.5;
  d[1] = 4.5 * t2 - 5.0 * t;
  d[2] = -4.5 * t2 + 4.0 * t + 0.5;
  d[3] = 1.5 * t2 - t;
}

}  // namespace

PatternTemplate::PatternTemplate(const SensorConfig& config) {
  // The detector seen from every shift the field allows (a degree beyond
  // it), and a margin for the interpolation.
  const double height_um = (config.mask.height_mm + 0.5 * config.mask.thickness_mm) * 1000.0;
  const double shift_um =
      height_um * std::tan(degToRad(std::max(config.fov.alpha_max_deg, config.fov.beta_max_deg) + 1.0));
  const double half_um =
      0.5 * std::max(config.detector.width_px, config.detector.height_px) * config.detector.pitch_um + shift_um;
  pitch_um_ = config.detector.pitch_um;
  side_px_ = 2 * static_cast<int>(std::ceil(half_um / pitch_um_)) + 8;
  // Same pixel phase as the detector: both centres on a pixel corner or both on a pixel centre.
  if ((side_px_ - config.detector.width_px) % 2 != 0) ++side_px_;
  if (side_px_ > limits::kMaxDetectorSidePx)
    throw std::invalid_argument("pattern template of " + std::to_string(side_px_) + " px exceeds the limit of " +
                                std::to_string(limits::kMaxDetectorSidePx) + " px (field or height too large)");
  SensorConfig wide = config;
  wide.detector.width_px = wide.detector.height_px = side_px_;
  centre_px_ = 0.5 * (side_px_ - 1);
  const Renderer renderer(SensorInstance::nominalOf(wide));
  renderer.expectedElectrons(Eigen::Vector3d::UnitZ(), nullptr).convertTo(values_, CV_64F);
  double peak = 0.0;
  cv::minMaxLoc(values_, nullptr, &peak);
  if (!(peak > 0.0)) throw std::invalid_argument("pattern template: the design puts no light on the detector");
  values_ /= peak;
}

double PatternTemplate::at(double x_um, double y_um, double* grad_x, double* grad_y) const {
  const double u = x_um / pitch_um_ + centre_px_, v = y_um / pitch_um_ + centre_px_;
  const double fu = std::floor(u), fv = std::floor(v);
  if (!(fu >= 1.0 && fv >= 1.0 && fu + 2.0 < side_px_ && fv + 2.0 < side_px_)) {
    if (grad_x) *grad_x = 0.0;
    if (grad_y) *grad_y = 0.0;
    return 0.0;
  }
  const int iu = static_cast<int>(fu), iv = static_cast<int>(fv);
  double wu[4], wv[4], du[4], dv[4];
  cubicWeights(u - fu, wu, du);
  cubicWeights(v - fv, wv, dv);
  double value = 0.0, gx = 0.0, gy = 0.0;
  for (int j = 0; j < 4; ++j) {
    const double* row = values_.ptr<double>(iv - 1 + j) + (iu - 1);
    const double along = wu[0] * row[0] + wu[1] * row[1] + wu[2] * row[2] + wu[3] * row[3];
    const double slope = du[0] * row[0] + du[1] * row[1] + du[2] * row[2] + du[3] * row[3];
    value += wv[j] * along;
    gx += wv[j] * slope;
    gy += dv[j] * along;
  }
  if (grad_x) *grad_x = gx / pitch_um_;
  if (grad_y) *grad_y = gy / pitch_um_;
  return value;
}

}  // namespace dss
