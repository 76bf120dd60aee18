// The light pattern of a mask whose spots merge (a coded mask of
// overlapping apertures under a threshold, e.g. thesis_ca): no spot can be
// told apart, but the whole pattern moves with the sun as one piece. The
// template is the design's own noise-free irradiance at normal incidence,
// rendered by the simulator's optics on a detector large enough to hold
// every spot and the field's whole shift, normalised to a peak of 1, and
// read at any shift by bicubic (Catmull-Rom) interpolation with its gradient.
#pragma once

#include <cstddef>
#include <opencv2/core.hpp>
#include <vector>

#include "digital_sun_sensor/sim/sensor_config.h"

namespace dss {

class PatternTemplate {
 public:
  // Renders the design of `config` (as drawn: no as-built errors, no
  // anomalies). Throws std::invalid_argument when the template would exceed
  // the detector size limit.
  explicit PatternTemplate(const SensorConfig& config);

  // The template as a detector of the template's pitch sees it when the
  // pattern is shifted by (shift_x, shift_y) um. Every pixel shares one
  // sub-pixel phase, so the bicubic weights are computed once per shift,
  // not once per pixel (the pattern solve reads tens of thousands of pixels
  // per Gauss-Newton iteration).
  class Shifted {
   public:
    // Value at detector pixel (col, row) and its gradient [1/um] with
    // respect to the position on the detector; outside the rendered area 0.
    double at(int col, int row, double& grad_x, double& grad_y) const;
    // The value alone (a third of the work).
    double at(int col, int row) const;
    // at() for pixels (col + i, row), i < count, into value[i], grad_x[i],
    // grad_y[i]: the same results, computed along the row so that the
    // compiler can vectorise across pixels.
    void run(int col, int row, int count, double* value, double* grad_x, double* grad_y) const;
    // The values alone.
    void run(int col, int row, int count, double* value) const;

   private:
    friend class PatternTemplate;
    // The template's values, row stride [values] and side, taken once (a
    // read of the cv::Mat's fields per row cost the subsample fits ~2 %).
    const double* data_ = nullptr;
    std::size_t stride_ = 0;
    int side_ = 0;
    int base_u_ = 0, base_v_ = 0;           // template column, row of the interpolation origin of pixel (0, 0)
    double wu_[4], wv_[4], du_[4], dv_[4];  // weights, and their derivatives per um
  };
  // The detector (width x height pixels of the template's pitch) centred
  // on the pattern's centre at zero shift.
  Shifted shifted(int detector_width_px, int detector_height_px, double shift_x_um, double shift_y_um) const;

  // The detector's pixels where the template shifted by (shift_x, shift_y)
  // um reaches a share of its brightest value on the detector (read at the
  // nearest template pixel; no interpolation), for one share at many
  // shifts. Where the detector holds one of the template's brightest
  // pixels (its peak, 1: over 60 % of thesis_ca's field) they are a window
  // of one byte mask made once; elsewhere the template's values are
  // compared per shift.
  class Reach {
   public:
    Reach(const PatternTemplate& pattern, double fraction);
    // Sets those pixels of `mask` (CV_8U, the detector's size) to 255, the others left as they are.
    void mark(cv::Mat& mask, double shift_x_um, double shift_y_um) const;

   private:
    const PatternTemplate* pattern_;
    double fraction_;
    cv::Mat at_peak_;  // CV_8U: the template's pixels at or above fraction_ of its peak
  };
  // CV_8U: the pixels Reach marks (255) on an unmarked detector.
  cv::Mat reaching(int detector_width_px, int detector_height_px, double shift_x_um, double shift_y_um,
                   double fraction) const;

  int sidePx() const { return side_px_; }
  double pitchUm() const { return pitch_um_; }
  const cv::Mat& values() const { return values_; }  // CV_64F, side x side

 private:
  // The brightest value on a window of the template: the maxima of the
  // kMaxBlockPx blocks it covers whole, and the pixels of its edges.
  double peakIn(const cv::Rect& window) const;
  static constexpr int kMaxBlockPx = 16;

  cv::Mat values_;
  cv::Mat block_max_;  // CV_64F: the maximum of each kMaxBlockPx x kMaxBlockPx block of values_
  // Pixels holding the template's peak, 1 (up to kPeakPixels: a periodic
  // mask repeats it; thesis_ca's three lie 325 px apart in a row).
  std::vector<cv::Point> peak_px_;
  static constexpr std::size_t kPeakPixels = 16;
  int side_px_ = 0;
  double pitch_um_ = 1.0;
  double centre_px_ = 0.0;
};

// Inline: the pattern solve calls it for every pixel of every iteration.
inline double PatternTemplate::Shifted::at(int col, int row, double& grad_x, double& grad_y) const {
  const int iu = col + base_u_, iv = row + base_v_;
  const int side = side_;
  if (iu < 1 || iv < 1 || iu + 2 >= side || iv + 2 >= side) {
    grad_x = grad_y = 0.0;
    return 0.0;
  }
  double value = 0.0, gx = 0.0, gy = 0.0;
  for (int j = 0; j < 4; ++j) {
    const double* r = data_ + static_cast<std::size_t>(iv - 1 + j) * stride_ + (iu - 1);
    const double along = wu_[0] * r[0] + wu_[1] * r[1] + wu_[2] * r[2] + wu_[3] * r[3];
    const double slope = du_[0] * r[0] + du_[1] * r[1] + du_[2] * r[2] + du_[3] * r[3];
    value += wv_[j] * along;
    gx += wv_[j] * slope;
    gy += dv_[j] * along;
  }
  grad_x = gx;
  grad_y = gy;
  return value;
}

inline double PatternTemplate::Shifted::at(int col, int row) const {
  const int iu = col + base_u_, iv = row + base_v_;
  const int side = side_;
  if (iu < 1 || iv < 1 || iu + 2 >= side || iv + 2 >= side) return 0.0;
  double value = 0.0;
  for (int j = 0; j < 4; ++j) {
    const double* r = data_ + static_cast<std::size_t>(iv - 1 + j) * stride_ + (iu - 1);
    value += wv_[j] * (wu_[0] * r[0] + wu_[1] * r[1] + wu_[2] * r[2] + wu_[3] * r[3]);
  }
  return value;
}

}  // namespace dss
