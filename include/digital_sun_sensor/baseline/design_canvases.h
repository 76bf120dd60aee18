// The design's noise-free image near any incidence without rendering its
// spots: one wide render per node of the diffraction cache's angle grid
// (the spots shaped as at that node, placed a whole number of pixels from
// the apertures so that every canvas shares one sub-pixel phase, reaching
// every shift of the node's cells). An image blends the canvases of its
// incidence's nodes with the cache's bilinear weights in angle, as the
// renderer blends the nodes' spot shapes, and reads the blend at its shift
// by one bicubic interpolation: ~20 multiply-adds per pixel, where a
// thesis_ca render resamples and adds ~50 overlapping spots.
// It is not the renderer's image to the bit: the irradiance agrees to a few
// 1e-5 of the peak on average (the bicubic read of pixel samples against the
// renderer's bilinear read of 1 um samples; up to 2e-3 where a spot map's
// crop ends), which moves ~1 % of the lit pixels by one ADC code. The
// pattern estimator decides with it only where the decision is clear by a
// margin that covers that (PatternEstimator::kCanvasZMargin). Memory: a
// float per pixel of the wider detector per node (thesis_ca's 121: 195 MB),
// built on first use or by warmUp (0.2 s on two cores once the diffraction
// cache is warm).
#pragma once

#include <Eigen/Core>
#include <atomic>
#include <memory>
#include <mutex>
#include <opencv2/core.hpp>
#include <optional>
#include <vector>

#include "digital_sun_sensor/sim/renderer.h"

namespace dss {

class NoiseFreeReadout;

class DesignCanvases {
 public:
  // For the nominal design of `design` (a flat mask: every aperture drifts
  // alike; `design` outlives this), its field of view plus `margin_deg`.
  DesignCanvases(const Renderer& design, double margin_deg);
  ~DesignCanvases();
  DesignCanvases(const DesignCanvases&) = delete;
  DesignCanvases& operator=(const DesignCanvases&) = delete;

  // The design's noise-free image (codes, CV_16U) at these angles, lit only
  // on the pixels `only` marks (CV_8U; nullptr: all), the exposure following
  // its brightest marked pixel as Renderer's; nullopt where a canvas does
  // not reach (outside the field plus the margin) or was not made.
  std::optional<cv::Mat> image(const Eigen::Vector2d& angles_rad, const cv::Mat* only) const;

  // Renders every node's canvas on `threads` threads (else each on first use).
  void warmUp(int threads) const;
  std::size_t bytesHeld() const;
  std::size_t bytesWhole() const;  // once every node's canvas is built

 private:
  struct Canvas;
  const Canvas& canvas(int ix, int iy) const;
  Eigen::Vector2d driftUm(const Eigen::Vector3d& sun) const;

  const Renderer& design_;
  std::unique_ptr<Renderer> wide_;  // the design on a detector `margin_px_` wider on each side
  std::unique_ptr<NoiseFreeReadout> readout_;
  double step_rad_ = 0.0;  // the cache's node step (0: far field, one node)
  int margin_px_ = 0;
  int nodes_x_ = 0, nodes_y_ = 0;  // nodes -nodes_x_ .. nodes_x_ (and y)
  mutable std::vector<std::unique_ptr<Canvas>> canvases_;
  mutable std::vector<std::once_flag> built_;
  mutable std::atomic<std::size_t> bytes_{0};
};

}  // namespace dss
