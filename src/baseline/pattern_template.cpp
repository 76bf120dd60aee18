#include "digital_sun_sensor/baseline/pattern_template.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include "digital_sun_sensor/common/cubic_weights.h"
#include "digital_sun_sensor/common/limits.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/common/vector_clones.h"
#include "digital_sun_sensor/sim/renderer.h"

namespace dss {

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
  for (int v = 0; v < side_px_ && peak_px_.size() < kPeakPixels; ++v)
    for (int u = 0; u < side_px_ && peak_px_.size() < kPeakPixels; ++u)
      if (values_.at<double>(v, u) == 1.0) peak_px_.emplace_back(u, v);
  const int blocks = side_px_ / kMaxBlockPx;  // whole blocks only: the rest is an edge
  block_max_.create(blocks, blocks, CV_64F);
  for (int j = 0; j < blocks; ++j)
    for (int i = 0; i < blocks; ++i) {
      double block_peak = 0.0;
      cv::minMaxLoc(values_(cv::Rect(i * kMaxBlockPx, j * kMaxBlockPx, kMaxBlockPx, kMaxBlockPx)), nullptr,
                    &block_peak);
      block_max_.at<double>(j, i) = block_peak;
    }
}

double PatternTemplate::peakIn(const cv::Rect& window) const {
  double peak = -std::numeric_limits<double>::infinity();
  auto take = [&peak](const cv::Mat& image, const cv::Rect& part) {
    if (part.width <= 0 || part.height <= 0) return;
    double part_peak = 0.0;
    cv::minMaxLoc(image(part), nullptr, &part_peak);
    peak = std::max(peak, part_peak);
  };
  // Whole blocks [i0, i1) x [j0, j1), pixels [x0, x1) x [y0, y1).
  const int i0 = (window.x + kMaxBlockPx - 1) / kMaxBlockPx, i1 = (window.x + window.width) / kMaxBlockPx;
  const int j0 = (window.y + kMaxBlockPx - 1) / kMaxBlockPx, j1 = (window.y + window.height) / kMaxBlockPx;
  if (i1 <= i0 || j1 <= j0) {
    take(values_, window);
    return peak;
  }
  take(block_max_, cv::Rect(i0, j0, i1 - i0, j1 - j0));
  const int x0 = i0 * kMaxBlockPx, x1 = i1 * kMaxBlockPx, y0 = j0 * kMaxBlockPx, y1 = j1 * kMaxBlockPx;
  const int right = window.x + window.width, bottom = window.y + window.height;
  take(values_, cv::Rect(window.x, window.y, window.width, y0 - window.y));  // above the blocks
  take(values_, cv::Rect(window.x, y1, window.width, bottom - y1));          // below
  take(values_, cv::Rect(window.x, y0, x0 - window.x, y1 - y0));             // left of them
  take(values_, cv::Rect(x1, y0, right - x1, y1 - y0));                      // right
  return peak;
}

PatternTemplate::Shifted PatternTemplate::shifted(int detector_width_px, int detector_height_px, double shift_x_um,
                                                  double shift_y_um) const {
  // Pixel (c, r) reads the template at u = c + (centre - (w - 1) / 2) - shift_x / pitch.
  const double u = centre_px_ - 0.5 * (detector_width_px - 1) - shift_x_um / pitch_um_;
  const double v = centre_px_ - 0.5 * (detector_height_px - 1) - shift_y_um / pitch_um_;
  const double fu = std::floor(u), fv = std::floor(v);
  Shifted s;
  s.data_ = values_.ptr<double>();
  s.stride_ = values_.step1();
  s.side_ = side_px_;
  s.base_u_ = static_cast<int>(fu);
  s.base_v_ = static_cast<int>(fv);
  cubicWeights(u - fu, s.wu_, s.du_);
  cubicWeights(v - fv, s.wv_, s.dv_);
  for (int k = 0; k < 4; ++k) {  // per um, not per pixel
    s.du_[k] /= pitch_um_;
    s.dv_[k] /= pitch_um_;
  }
  return s;
}

DSS_VECTOR_CLONES
void PatternTemplate::Shifted::run(int col, int row, int count, double* value, double* grad_x, double* grad_y) const {
  const int iu = col + base_u_, iv = row + base_v_;
  const int side = side_;
  if (iu < 1 || iv < 1 || iu + count + 1 >= side || iv + 2 >= side) {  // partly outside: pixel by pixel
    for (int i = 0; i < count; ++i) value[i] = at(col + i, row, grad_x[i], grad_y[i]);
    return;
  }
  // Row by row of the four taps, each summed in at()'s order (bit-identical results).
  for (int i = 0; i < count; ++i) value[i] = grad_x[i] = grad_y[i] = 0.0;
  for (int j = 0; j < 4; ++j) {
    const double* r = data_ + static_cast<std::size_t>(iv - 1 + j) * stride_ + (iu - 1);
    const double wv = wv_[j], dv = dv_[j];
    for (int i = 0; i < count; ++i) {
      const double along = wu_[0] * r[i] + wu_[1] * r[i + 1] + wu_[2] * r[i + 2] + wu_[3] * r[i + 3];
      const double slope = du_[0] * r[i] + du_[1] * r[i + 1] + du_[2] * r[i + 2] + du_[3] * r[i + 3];
      value[i] += wv * along;
      grad_x[i] += wv * slope;
      grad_y[i] += dv * along;
    }
  }
}

DSS_VECTOR_CLONES
void PatternTemplate::Shifted::run(int col, int row, int count, double* value) const {
  const int iu = col + base_u_, iv = row + base_v_;
  const int side = side_;
  if (iu < 1 || iv < 1 || iu + count + 1 >= side || iv + 2 >= side) {
    for (int i = 0; i < count; ++i) value[i] = at(col + i, row);
    return;
  }
  for (int i = 0; i < count; ++i) value[i] = 0.0;
  for (int j = 0; j < 4; ++j) {
    const double* r = data_ + static_cast<std::size_t>(iv - 1 + j) * stride_ + (iu - 1);
    const double wv = wv_[j];
    for (int i = 0; i < count; ++i)
      value[i] += wv * (wu_[0] * r[i] + wu_[1] * r[i + 1] + wu_[2] * r[i + 2] + wu_[3] * r[i + 3]);
  }
}

PatternTemplate::Reach::Reach(const PatternTemplate& pattern, double fraction)
    : pattern_(&pattern), fraction_(fraction), at_peak_(pattern.values_ >= fraction) {}

void PatternTemplate::Reach::mark(cv::Mat& mask, double shift_x_um, double shift_y_um) const {
  const PatternTemplate& p = *pattern_;
  const int w = mask.cols, h = mask.rows;
  if (mask.type() != CV_8U) throw std::invalid_argument("pattern template: the reach mask is not CV_8U");
  if (fraction_ <= 0.0) {  // the part off the template reads 0, which reaches it too
    mask.setTo(255);
    return;
  }
  // Pixel (c, r) lies nearest template pixel (c + u0, r + v0).
  const int u0 = static_cast<int>(std::lround(p.centre_px_ - 0.5 * (w - 1) - shift_x_um / p.pitch_um_));
  const int v0 = static_cast<int>(std::lround(p.centre_px_ - 0.5 * (h - 1) - shift_y_um / p.pitch_um_));
  const cv::Rect inside = cv::Rect(u0, v0, w, h) & cv::Rect(0, 0, p.side_px_, p.side_px_);
  if (inside.area() == 0) return;
  // The part of the detector off the template reads 0: the peak is the covered part's (at least 0).
  const bool holds_peak =
      std::any_of(p.peak_px_.begin(), p.peak_px_.end(), [&](const cv::Point& px) { return inside.contains(px); });
  const double peak = holds_peak ? 1.0 : p.peakIn(inside);
  if (!(peak > 0.0)) return;
  cv::Mat out = mask(inside - cv::Point(u0, v0));
  if (peak == 1.0)  // the template's own (its values are divided by it)
    cv::bitwise_or(out, at_peak_(inside), out);
  else
    cv::bitwise_or(out, p.values_(inside) >= fraction_ * peak, out);
}

cv::Mat PatternTemplate::reaching(int detector_width_px, int detector_height_px, double shift_x_um, double shift_y_um,
                                  double fraction) const {
  cv::Mat out = cv::Mat::zeros(detector_height_px, detector_width_px, CV_8U);
  Reach(*this, fraction).mark(out, shift_x_um, shift_y_um);
  return out;
}

}  // namespace dss
