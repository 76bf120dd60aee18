// Sun angles from the whole light pattern of a mask whose spots merge
// (baseline/pattern_template.h): the image is modelled as the template
// shifted by the sun's lateral drift at the mask's mid-plane, scaled by an
// unknown gain and passed through the sensor's threshold,
//   value(x) = max(floor, gain * P(x - d(alpha, beta)) - offset),
// a pixel below the threshold reading as censored. A coarse-to-fine search
// over the field's shifts (block-averaged template, normalised correlation)
// finds where the pattern lies; Gauss-Newton on every lit pixel and its dark
// neighbours then fits (alpha, beta, gain). Torch-free.
#pragma once

#include <Eigen/Core>
#include <functional>
#include <limits>
#include <memory>
#include <opencv2/core.hpp>
#include <optional>
#include <vector>

#include "digital_sun_sensor/baseline/calibration_model.h"
#include "digital_sun_sensor/baseline/pattern_template.h"
#include "digital_sun_sensor/sim/sensor_config.h"

namespace dss {

struct PatternSolveOptions {
  int coarse_factor = 16;        // block size of the global search [px]
  int middle_factor = 2;         // finest block size of the local search around each candidate,
                                 // which halves the coarse one down to it [px]
  int candidates = 6;            // global search peaks refined...
  int candidate_stride = 8;      // ...on every this-many-th pixel (thesis_ca: 4 cost 10 % more
                                 // instructions for estimates within 9e-6 deg)...
  int candidate_iterations = 4;  // ...by this many Gauss-Newton iterations
  int iterations = 10;           // then the best on every pixel
  int dark_band_px = 2;          // dark pixels this close to a lit one enter the fit (censored)
};

struct PatternSolution {
  Eigen::Vector2d angles_rad = Eigen::Vector2d::Zero();
  // (J^T J)^-1 times the residual variance per pixel [rad^2].
  Eigen::Matrix2d covariance = Eigen::Matrix2d::Zero();
  double gain = 0.0;
  double residual_rms_dn = 0.0;  // of the pixels in the fit
  int pixels = 0;                // in the final fit
  int iterations = 0;
  // The best fit elsewhere in the field (more than kDistinctDeg away) and
  // its residual RMS over this one's: near 1, the image fits both (a mask
  // whose pattern repeats within the field). Infinity: no other fit.
  Eigen::Vector2d alternative_rad = Eigen::Vector2d::Zero();
  double alternative_cost_ratio = std::numeric_limits<double>::infinity();
  static constexpr double kDistinctDeg = 0.1;
};

// Where the answer must lie (e.g. the quadrant a coarse sun sensor gives):
// fits outside it are not considered.
struct AngleWindow {
  Eigen::Vector2d min_rad, max_rad;
  bool contains(const Eigen::Vector2d& angles_rad) const {
    return (angles_rad.array() >= min_rad.array()).all() && (angles_rad.array() <= max_rad.array()).all();
  }
};

class PatternSolver {
 public:
  // Renders the template (seconds for a large mask). Throws
  // std::invalid_argument where the config has no light pattern to fit.
  explicit PatternSolver(const SensorConfig& config, PatternSolveOptions options = {});
  ~PatternSolver();

  // Whether the fit on every pixel starts at the search's runner-up (a
  // place more than kDistinctDeg away) instead of its best: for a caller
  // that tells two places apart itself. It is given both candidates' fits
  // on the subsample, and is asked before the fit on every pixel (the
  // costliest step), which then runs at one place only.
  using RunnerUpChoice = std::function<bool(const PatternSolution& best, const PatternSolution& runner_up)>;

  // nullopt: no lit pixel, or no shift in the field (in `window`, when
  // given) explains the light. The image must have the config's size
  // (CV_8U or CV_16U). Where `choose` takes the runner-up, the solution is
  // fitted there (and may leave the window), and the best candidate is its
  // alternative.
  std::optional<PatternSolution> solve(const cv::Mat& image, const std::optional<AngleWindow>& window = {},
                                       const RunnerUpChoice& choose = {}) const;

  // The pattern's lateral drift [um] at the given sun angles (the spot of
  // an aperture at the mask centre, through any cover glass).
  Eigen::Vector2d shiftUm(const Eigen::Vector2d& angles_rad) const;

  const PatternTemplate& patternTemplate() const { return *template_; }

  // Candidates are screened by their residual at the start, on every
  // (this x candidate_stride)-th pixel: those above kScreenRatio x the best
  // candidate's are not refined. Of 1200 thesis_ca candidates (200 images,
  // screens on every 16th pixel), the 381 whose fit came within 1.5 x the
  // best fit started within 1.21 x the best start; the other 819 started
  // 2.74 x or more above it.
  static constexpr int kScreenStrideFactor = 4;
  static constexpr double kScreenRatio = 2.0;
  // Before that, candidates whose score at the level of blocks twice the
  // finest falls below this share of the best candidate's are dropped. On
  // thesis_ca (13 300 candidates: nominal, alias band, ghosts, stray
  // light) the refined ones scored 0.982 or more of the best there, the
  // others 0.935 or less.
  static constexpr double kKeepScoreShare = 0.96;
  // Gauss-Newton stops after a step below this share of the solution's sigma.
  static constexpr double kConvergedSigmaShare = 0.3;

 private:
  struct Pixels;
  struct Level;
  // The image's pixels into px (its buffers reused).
  void pixelsOf(const cv::Mat& image, Pixels& px) const;
  // Gauss-Newton on every `stride`-th pixel, from `gain` where given (else
  // the gain that best explains the lit pixels at the start).
  std::optional<PatternSolution> fit(const Pixels& pixels, Eigen::Vector2d angles, int stride, int iterations,
                                     std::optional<double> gain = {}) const;
  Eigen::Vector2d anglesOfShift(const Eigen::Vector2d& shift_um) const;

  SensorConfig config_;
  PatternSolveOptions options_;
  std::shared_ptr<const PatternTemplate> template_;
  MaskGeometry drift_;  // one aperture at the mask centre, at the mid-plane height
  double offset_ = 0.0, floor_ = 0.0, top_ = 0.0;
  std::vector<Level> levels_;  // block-averaged templates: coarse, middle
};

}  // namespace dss
