#include "digital_sun_sensor/estimate/tracking_prior.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/sim/geometry.h"

namespace dss {

void TrackingOptions::validate() const {
  if (!(max_rate_deg_s >= 0.0) || !std::isfinite(max_rate_deg_s))
    throw std::invalid_argument("tracking/max_rate_deg_s must be >= 0 (0: no tracking), not " +
                                std::to_string(max_rate_deg_s));
  if (!(max_age_s > 0.0) || !std::isfinite(max_age_s))
    throw std::invalid_argument("tracking/max_age_s must be > 0, not " + std::to_string(max_age_s));
}

TrackingPrior::TrackingPrior(TrackingOptions options) : options_(options) { options_.validate(); }

bool TrackingPrior::update(double stamp_s, const SunEstimate& estimate) {
  if (!options_.enabled() || !estimate.valid || !std::isfinite(stamp_s)) return false;
  const std::optional<CoarseDirection> prior = fromLast(stamp_s);
  const bool contradicted = prior && beyond(*prior, estimate);
  const double variance = std::max(estimate.covariance[0], estimate.covariance[3]);
  if (!std::isfinite(estimate.alpha_rad) || !std::isfinite(estimate.beta_rad) || !(variance >= 0.0) ||
      !std::isfinite(variance))
    return contradicted;
  // Counted up to kAgreeingAnswers (a count of every answer would overflow in a long mission).
  const int agreeing = prior && !contradicted ? std::min(last_->agreeing + 1, kAgreeingAnswers) : 0;
  last_ = Answer{stamp_s, estimate.alpha_rad, estimate.beta_rad, std::sqrt(variance), agreeing};
  return contradicted;
}

std::optional<CoarseDirection> TrackingPrior::at(double stamp_s) const {
  if (!last_ || last_->agreeing < kAgreeingAnswers) return std::nullopt;
  return fromLast(stamp_s);
}

std::optional<CoarseDirection> TrackingPrior::fromLast(double stamp_s) const {
  if (!last_ || !options_.enabled()) return std::nullopt;
  const double age_s = stamp_s - last_->stamp_s;
  if (!(age_s >= 0.0) || age_s > options_.max_age_s) return std::nullopt;
  // The sun moves at most `turn` on the sky. alpha turns about the sensor's
  // y axis, so a move of d on the sky changes it by at most d over the
  // distance from that axis, cos(the direction's angle from the x-z plane),
  // which the move itself can shrink by up to `turn` (beta likewise about x).
  const double turn = degToRad(options_.max_rate_deg_s) * age_s;
  const Eigen::Vector3d sun = sunVectorFromAngles(last_->alpha_rad, last_->beta_rad);
  const double off_axis =
      std::max(std::asin(std::min(1.0, std::abs(sun.x()))), std::asin(std::min(1.0, std::abs(sun.y())))) + turn;
  if (!(off_axis < 0.5 * kPi)) return std::nullopt;
  return CoarseDirection{last_->alpha_rad, last_->beta_rad, last_->sigma_rad + turn / std::cos(off_axis)};
}

bool TrackingPrior::contradicts(double stamp_s, const SunEstimate& estimate) const {
  const std::optional<CoarseDirection> prior = fromLast(stamp_s);
  return prior && beyond(*prior, estimate);
}

bool TrackingPrior::beyond(const CoarseDirection& prior, const SunEstimate& estimate) const {
  if (!estimate.valid) return false;
  // The prior's sigma is the last answer's plus the bound's reach.
  const double reach = prior.sigma_rad - last_->sigma_rad;
  const double variance = std::max(estimate.covariance[0], estimate.covariance[3]);
  const double limit = reach + kNoiseSigmas * std::sqrt(last_->sigma_rad * last_->sigma_rad + std::max(0.0, variance));
  return std::abs(estimate.alpha_rad - prior.alpha_rad) > limit || std::abs(estimate.beta_rad - prior.beta_rad) > limit;
}

}  // namespace dss
