// Checks around any sun estimator, so that a consumer never gets an estimate
// from an image it should not trust: the image is screened before estimation
// (saturation) and each estimate after it (predicted uncertainty beyond the
// training envelope, angles beyond the field of view). Failed checks give
// valid = false with the reason in status.
#pragma once

#include <functional>
#include <memory>

#include "digital_sun_sensor/common/spike_filter.h"
#include "digital_sun_sensor/common/sun_estimate.h"

namespace dss {

struct ScreenOptions {
  // Lit groups (8-connected pixels above the input threshold) smaller than
  // this are removed before estimation: hot pixels and single noise spikes,
  // which the SSCNN would otherwise take as light (0: keep everything).
  int min_spot_px = 5;
  // Pixels brighter than all 8 neighbours by more than this many noise
  // standard deviations (common/spike_filter.h) are replaced by the median of
  // those neighbours: hot pixels inside or beside a spot (0: off).
  double spike_sigmas = kDefaultSpikeSigmas;
  // More pixels than this fraction of the detector at the top code: "saturated".
  double max_saturated_fraction = 0.01;
  // A predicted 1-sigma (either axis) above this: "out_of_distribution". Only
  // a model whose variance head grows on inputs unlike its training images
  // trips it; with a constant sigma (sigma_mode: constant) the SSCNN's input
  // envelope does that work (model/input_envelope).
  double max_sigma_deg = 0.01;
  // An estimate further than this beyond the config's field of view: "outside_fov".
  double fov_margin_deg = 0.25;

  // Throws std::invalid_argument naming the first bad field.
  void validate() const;
};

// A copy of `image` without its lit groups (pixels above `threshold_dn`,
// 8-connected) of fewer than `min_px` pixels, which are set to `floor_dn`; the
// image itself when there are none.
cv::Mat removeSmallSpots(const cv::Mat& image, double threshold_dn, double floor_dn, int min_px);

// "saturated" or empty; `max_code` is the sensor's top digital number.
std::string screenImage(const cv::Mat& image, int max_code, const ScreenOptions& options);

// Turns a valid estimate invalid when it fails a check.
void screenEstimate(SunEstimate* estimate, const SensorConfig& sensor, const ScreenOptions& options);

class ScreenedEstimator : public SunEstimator {
 public:
  ScreenedEstimator(std::unique_ptr<SunEstimator> inner, ScreenOptions options);

  std::string source() const override { return inner_->source(); }
  const SensorConfig& sensor() const override { return inner_->sensor(); }
  std::vector<SunEstimate> estimate(const std::vector<cv::Mat>& images) override;
  // The hints of the images that pass go to the inner estimator.
  std::vector<SunEstimate> estimateWithSubFovHints(const std::vector<cv::Mat>& images,
                                                   const std::vector<int>& subfov_classes) override;
  // The coarse directions of the images that pass go to the inner estimator.
  std::vector<SunEstimate> estimateWithCoarseDirections(const std::vector<cv::Mat>& images,
                                                        const CoarseDirections& coarse) override;
  void warmUp(int threads) const override { inner_->warmUp(threads); }

  // The image as the inner estimator is given it: hot pixels repaired and lit
  // groups under min_spot_px removed (what a consumer that re-reads the same
  // images, such as in-flight recalibration, should read). An image the
  // screen cannot read (empty, not 8/16-bit mono) comes back as it is.
  cv::Mat screenedImage(const cv::Mat& image) const;

 private:
  // Screens the images and estimates those that pass by `run(passed, where)`
  // (`where`: their indices among `images`).
  using Run = std::function<std::vector<SunEstimate>(const std::vector<cv::Mat>&, const std::vector<std::size_t>&)>;
  std::vector<SunEstimate> screenAndEstimate(const std::vector<cv::Mat>& images, const Run& run);

  std::unique_ptr<SunEstimator> inner_;
  ScreenOptions options_;
  int max_code_;
  double threshold_dn_, black_level_dn_;
  std::vector<int> spike_margin_dn_;
};

}  // namespace dss
