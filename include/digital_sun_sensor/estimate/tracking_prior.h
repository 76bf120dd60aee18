// The estimator's own last answer as a coarse direction for the images that
// follow (tracking). Where a mask's pattern repeats within the field
// (thesis_ca: two places 5.74 deg apart that are mirror images of each
// other), the image alone cannot choose between them; but the sun cannot
// have moved farther than the spacecraft's rate allows since the last
// answer. The prior's sigma is the answer's own plus a bound on the sun's
// angular rate in the sensor frame times the time since, so it only
// decides while that bound holds and the answer is recent (the estimator
// needs a place 3 sigma nearer; PatternEstimator::kCoarseDecisionSigmas).
// A bound the motion breaks shows as answers farther from the one before
// than it allows (contradicts()): the prior is only given while the last
// kAgreeingAnswers answers each lay within it of the one before, so that a
// sun faster than the bound leaves the alias declined rather than chosen
// from a place the sun has left. Torch-free header.
#pragma once

#include <optional>

#include "digital_sun_sensor/common/sun_estimate.h"

namespace dss {

struct TrackingOptions {
  double max_rate_deg_s = 0.0;  // bound on the sun's angular rate in the sensor frame; 0: no tracking
  double max_age_s = 1.0;       // an answer older than this gives no prior

  bool enabled() const { return max_rate_deg_s > 0.0; }
  // Throws std::invalid_argument naming the first bad value.
  void validate() const;
};

class TrackingPrior {
 public:
  // An answer contradicts the prior beyond the rate bound's reach plus this
  // many sigmas of the two answers' difference.
  static constexpr double kNoiseSigmas = 5.0;
  // Answers in a row within the bound of the one before, before a prior is given.
  static constexpr int kAgreeingAnswers = 2;

  explicit TrackingPrior(TrackingOptions options = {});

  // The latest answer becomes the prior (whatever its stamp: a replay that
  // restarts starts the prior over); invalid or non-finite ones are ignored.
  // Returns whether it contradicted the last one (contradicts()).
  bool update(double stamp_s, const SunEstimate& estimate);
  // The prior for an image at stamp_s [s]: none when tracking is off, before
  // the first answer, for an image stamped before the answer or more than
  // max_age_s after it, where the rate bound reaches 90 deg off axis, or
  // before kAgreeingAnswers answers in a row agreed with the one before.
  std::optional<CoarseDirection> at(double stamp_s) const;
  // Whether a valid answer at stamp_s lies farther from the last answer, on
  // either axis, than the rate bound allows in the time between them plus
  // kNoiseSigmas of their difference's sigma (false without a recent answer).
  bool contradicts(double stamp_s, const SunEstimate& estimate) const;
  bool enabled() const { return options_.enabled(); }

 private:
  struct Answer {
    double stamp_s;
    double alpha_rad, beta_rad, sigma_rad;
    int agreeing;  // answers in a row, up to this one, within the bound of the one before (at most kAgreeingAnswers)
  };
  // The prior from the last answer, whether or not it agreed.
  std::optional<CoarseDirection> fromLast(double stamp_s) const;
  // Whether a valid answer lies beyond `prior` (fromLast's) as contradicts() says.
  bool beyond(const CoarseDirection& prior, const SunEstimate& estimate) const;
  TrackingOptions options_;
  std::optional<Answer> last_;
};

}  // namespace dss
