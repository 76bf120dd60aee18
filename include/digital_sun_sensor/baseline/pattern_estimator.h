// The conventional estimator for masks whose spots merge (thesis_ca), where
// the centroid chain finds no spot to match: the whole-pattern solve
// (baseline/pattern_solve.h) on the sensor's design, no training and no
// calibration. Where the pattern repeats within the field, an image that
// fits two places about equally is decided by the design's image at each
// (from its canvases where they decide by a margin, else rendered); if
// that cannot tell them apart either, it is answered
// ambiguous_aperture, with the better fit's angles. An answer whose image
// holds light the design does not (a ghost, stray light: its chi^2 excess,
// AliasEvidence::unexplained_z, above kMaxUnexplainedZ) is declined
// model_mismatch: such light biases the solve beyond its sigma. Below
// that, the variance grows with the excess (varianceInflation).
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <memory>
#include <optional>
#include <vector>

#include "digital_sun_sensor/baseline/calibration_model.h"
#include "digital_sun_sensor/baseline/design_canvases.h"
#include "digital_sun_sensor/baseline/pattern_solve.h"
#include "digital_sun_sensor/common/sun_estimate.h"
#include "digital_sun_sensor/model/input_spec.h"
#include "digital_sun_sensor/sim/pixel_noise.h"
#include "digital_sun_sensor/sim/renderer.h"

namespace dss {

struct PatternEstimatorOptions {
  // The solve's covariance takes the residual as independent pixel noise;
  // the template's own error is not. Its scale per axis is measured at
  // construction on this many noisy images of the design (seeded, over
  // the field, each solved in its quadrant): RMS of error / sigma. 0: 1.
  int sigma_images = 64;
  std::uint64_t sigma_seed = 1;
  // Decisions first on the design's images from its canvases
  // (PatternEstimator::kCanvasZMargin); false: every design image rendered.
  bool design_canvases = true;
};

// How firmly an image I tells two places apart, from the design's
// noise-free image at each (H, T) and the detector's pixel variance v
// (sim/pixel_noise.h): z is the log-likelihood ratio of the two,
// sum ((I - T)^2 - (I - H)^2) / v, in standard deviations of its noise,
// 2 sqrt(sum (H - T)^2 / v) (> 0 favours H). A ghost or stray light can tip
// it by many deviations while its favoured place fits well where the two
// differ, so a decision also needs the image explained elsewhere:
// unexplained_z is the favoured place's chi^2 excess, (chi^2 - n) / sqrt(2n),
// over its n pixels inside the readout's linear range (on 500 nominal
// thesis_ca images -2.3 to 3.4; where a ghost had tipped the choice, 7 to 103).
struct AliasEvidence {
  static constexpr double kMinZ = 4.0;             // a wrong choice at 4 sigma: 3e-5 per decision
  static constexpr double kMaxUnexplainedZ = 5.0;  // light the design does not hold
  double z = 0.0;
  double unexplained_z = 0.0;
  bool decides() const { return std::abs(z) >= kMinZ && unexplained_z <= kMaxUnexplainedZ; }
};

class PatternEstimator : public SunEstimator {
 public:
  // An alternative fit inside the field (plus this margin) whose residual
  // is within this ratio of the best sends the image to the design's
  // rendered image at both places; it stays ambiguous unless their
  // AliasEvidence decides.
  static constexpr double kAmbiguousCostRatio = 1.01;
  // Pixels this many noise deviations inside the linear range enter unexplained_z.
  static constexpr double kLinearRangeSigmas = 2.5;
  static constexpr double kFieldMarginDeg = 0.25;
  // The design's images for a decision are rendered only on the pixels the
  // image lights and those where the template, at either place, reaches
  // kReachMargin of the share of its brightest that the threshold keeps;
  // where a design image lights a pixel on their edge, on every pixel. On
  // 566 thesis_ca design images (300 images' decisions, over the field and
  // in its alias band) these equalled whole renders on every pixel at 0.9
  // (63 000 of 262 144 pixels) without reaching the edge; at 0.95 (50 000)
  // they reached it in 23 %.
  static constexpr double kReachMargin = 0.9;
  // A decision and an excess are first made on the design's images from its
  // canvases (baseline/design_canvases.h) and taken from them where z lies
  // kCanvasZMargin beyond AliasEvidence::kMinZ and the excess at most
  // kCanvasMaxUnexplainedZ (below kExcessNoiseZ: no variance inflation, no
  // decline): the decision, the status and the sigma rendered images would
  // give. Else the design's images are rendered. On 370 thesis_ca decisions
  // (150 over the field, 150 in its alias band, 100 with a ghost; seeds
  // 9511-9513) the canvases' z differed from the rendered images' by at most
  // 0.94 and their excess by at most 0.19 wherever the excess stayed below
  // kMaxUnexplainedZ; 186 were taken from the canvases (127 of 133 over the
  // field), their rendered z 5.37 or more and their excess 1.56 or less.
  static constexpr double kCanvasZMargin = 1.5;
  static constexpr double kCanvasMaxUnexplainedZ = 1.6;
  // Canvases that would hold more than this are not made (thesis_ca's: 195 MB).
  static constexpr std::size_t kMaxDesignCanvasBytes = std::size_t{512} << 20;

  explicit PatternEstimator(const SensorConfig& config, const PatternEstimatorOptions& options = {});

  std::string source() const override { return "pattern"; }
  const SensorConfig& sensor() const override { return config_; }
  std::vector<SunEstimate> estimate(const std::vector<cv::Mat>& images) override;
  // Quadrant classes (quadrant sub-FOV sensors only): each image's answer is
  // sought in its quadrant (plus the field margin across its axes).
  std::vector<SunEstimate> estimateWithSubFovHints(const std::vector<cv::Mat>& images,
                                                   const std::vector<int>& subfov_classes) override;
  // Where the image fits two places about equally and the design's image at
  // each does not decide, the coarse direction chooses the place it lies
  // nearer by at least kCoarseDecisionSigmas of its sigma.
  std::vector<SunEstimate> estimateWithCoarseDirections(const std::vector<cv::Mat>& images,
                                                        const CoarseDirections& coarse) override;
  static constexpr double kCoarseDecisionSigmas = 3.0;
  // The design's spot shapes over the field, which its alias decisions and
  // unexplained-light check render, and its canvases (else computed on
  // first use: the first images of thesis_ca took up to seconds).
  void warmUp(int threads) const override {
    design_.warmUp(threads);
    if (canvases_) canvases_->warmUp(threads);
  }

  // Within `window` (default: the field of view plus the margin).
  SunEstimate estimateOne(const cv::Mat& image, const std::optional<AngleWindow>& window = {},
                          const std::optional<CoarseDirection>& coarse = {}) const;
  // The window of a quadrant hint: the quadrant plus the field margin across its axes.
  AngleWindow quadrantWindow(int quadrant) const;
  // The image at `here` against `there` (exposure and threshold as the sensor's).
  AliasEvidence aliasEvidence(const cv::Mat& image, const Eigen::Vector2d& here_rad,
                              const Eigen::Vector2d& there_rad) const;
  // The image's chi^2 excess over the design's image at these angles, (chi^2 - n) / sqrt(2n)
  // over the n pixels inside the readout's linear range (AliasEvidence::unexplained_z).
  double unexplainedLightZ(const cv::Mat& image, const Eigen::Vector2d& angles_rad) const;
  // What multiplies the solve's sigma per axis (PatternEstimatorOptions).
  const std::array<double, 2>& sigmaScale() const { return sigma_scale_; }
  // What multiplies an answer's variance at this chi^2 excess:
  // 1 + kVariancePerExcess * (unexplained_z - kExcessNoiseZ), 1 below
  // kExcessNoiseZ. Light the design does not hold biases the solve before
  // it declines the answer: on 585 thesis_ca ghost images answered
  // (seeds 9201, 9202, 9101), error / sigma had a mean square of 1.0-2.0
  // for an excess below 1, 1-8 from 2 to 3, 3-18 from 3 to 5; 297 nominal
  // ones, 1.0 at every excess (0.7-1.6 from 1 to 3). The constants are
  // fitted on seed 9201's: within 1 sigma 58 -> 67 %, within 3 sigma 93 ->
  // 97 %; seeds 9202 and 9101 59 -> 68 % and 64 -> 73 %, nominal 68.2 ->
  // 68.7 %.
  static constexpr double kExcessNoiseZ = 2.0;
  static constexpr double kVariancePerExcess = 3.0;
  static double varianceInflation(double unexplained_z) {
    return 1.0 + kVariancePerExcess * std::max(0.0, unexplained_z - kExcessNoiseZ);
  }

 private:
  // The design's noise-free image and an image's excess over one (both codes, CV_16U).
  cv::Mat designImage(const Eigen::Vector2d& angles_rad, const std::optional<cv::Mat>& only) const;
  // The pixels to render the design on for a decision between these places (nullopt: all).
  std::optional<cv::Mat> designPixels(const cv::Mat& image, const std::vector<Eigen::Vector2d>& places_rad) const;
  // The design's images at the places on `pixels`; where one lights a pixel
  // on their edge (its light may reach beyond them), all of them on every
  // pixel, and `pixels` reset.
  std::vector<cv::Mat> designImages(const std::vector<Eigen::Vector2d>& places_rad,
                                    std::optional<cv::Mat>& pixels) const;
  // Whether any of the images lights a pixel on the edge of `pixels`.
  bool lightsEdge(const std::vector<cv::Mat>& images, const cv::Mat& pixels) const;
  // The design's images at the places from its canvases; nullopt where a
  // canvas does not reach or one lights the edge of `pixels`.
  std::optional<std::vector<cv::Mat>> canvasImages(const std::vector<Eigen::Vector2d>& places_rad,
                                                   const std::optional<cv::Mat>& pixels) const;
  AliasEvidence evidenceOf(const cv::Mat& observed, const cv::Mat& here, const cv::Mat& there,
                           const std::optional<cv::Mat>& pixels) const;
  // Over the design's rendered `pixels` (all: nullopt).
  double unexplainedLightZ(const cv::Mat& observed, const cv::Mat& expected,
                           const std::optional<cv::Mat>& pixels) const;

  SensorConfig config_;
  InputSpec input_;
  PatternSolver solver_;
  Renderer design_;                           // the nominal design, for alias decisions
  std::unique_ptr<DesignCanvases> canvases_;  // its images without rendering, for the clear ones
  PixelNoise noise_;                          // its pixels' variance, for the same
  MaskGeometry geometry_;                     // the nominal design, for the sub-FOV class
  AngleWindow field_;
  std::array<double, 2> sigma_scale_{1.0, 1.0};
  std::optional<PatternTemplate::Reach> reach_;  // none: decisions render the whole detector
  std::vector<double> variance_of_half_sum_;     // of a value, per twice the value (the sum of two codes)
  std::vector<char> linear_code_;                // inLinearRange per code
  std::uint16_t unlit_code_ = 0;                 // a design pixel's without light
};

}  // namespace dss
