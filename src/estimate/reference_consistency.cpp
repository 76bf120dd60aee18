#include "digital_sun_sensor/estimate/reference_consistency.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

#include "digital_sun_sensor/common/units.h"

namespace dss {
namespace {

// Median of chi-square with one degree of freedom: median(x^2) / this is the
// variance of x when x is normal, and a few gross references (5 % of them 2-5
// degrees off) do not move it.
constexpr double kMedianChiSquare1 = 0.454936;

double robustRms(std::vector<double>& squares) {
  const auto middle = squares.begin() + static_cast<std::ptrdiff_t>(squares.size() / 2);
  std::nth_element(squares.begin(), middle, squares.end());
  return std::sqrt(*middle / kMedianChiSquare1);
}

}  // namespace

void ConsistencyOptions::validate() const {
  // Named as calibration_node's ~recalibration/ parameters.
  auto fail = [](const std::string& what) { throw std::invalid_argument(what); };
  if (min_pairs < 3) fail("consistency_min_pairs must be at least 3");
  if (window < min_pairs) fail("consistency_window must be at least consistency_min_pairs");
  if (!(reference_sigma_deg >= 0.0)) fail("reference_sigma_deg must be >= 0");
  if (!(max_normalized > 0.0)) fail("consistency_max_normalized must be positive");
}

ReferenceConsistency::ReferenceConsistency(ConsistencyOptions options) : options_(options) { options_.validate(); }

void ReferenceConsistency::add(const SunEstimate& estimate, const std::array<double, 2>& reference_rad) {
  Pair p{};
  const double reference2 = std::pow(degToRad(options_.reference_sigma_deg), 2);
  const double own2[2] = {estimate.covariance[0], estimate.covariance[3]};
  const double angle[2] = {estimate.alpha_rad, estimate.beta_rad};
  for (int axis = 0; axis < 2; ++axis) {
    p.residual_rad[axis] = angle[axis] - reference_rad[axis];
    p.expected_rad[axis] = std::sqrt(std::max(own2[axis], 0.0) + reference2);
    if (!std::isfinite(p.residual_rad[axis]) || !(p.expected_rad[axis] > 0.0)) return;
  }
  residuals_.push_back(p);
  if (residuals_.size() > options_.window) residuals_.pop_front();
  update();
}

void ReferenceConsistency::reset() {
  residuals_.clear();
  update();
}

void ReferenceConsistency::update() {
  normalized_ = {0.0, 0.0};
  extra_rad_ = {0.0, 0.0};
  if (residuals_.size() < options_.min_pairs) return;
  std::vector<double> normalized, raw;
  for (int axis = 0; axis < 2; ++axis) {
    normalized.clear();
    raw.clear();
    for (const Pair& p : residuals_) {
      normalized.push_back(std::pow(p.residual_rad[axis] / p.expected_rad[axis], 2));
      raw.push_back(std::pow(p.residual_rad[axis], 2));
    }
    normalized_[axis] = robustRms(normalized);
    if (normalized_[axis] > options_.max_normalized) extra_rad_[axis] = robustRms(raw);
  }
}

void ReferenceConsistency::widen(SunEstimate& estimate) const {
  if (!estimate.valid || !inconsistent()) return;
  estimate.covariance[0] += extra_rad_[0] * extra_rad_[0];
  estimate.covariance[3] += extra_rad_[1] * extra_rad_[1];
  for (int axis = 0; axis < 2; ++axis)
    estimate.model_sigma_rad[axis] = std::hypot(estimate.model_sigma_rad[axis], extra_rad_[axis]);
}

}  // namespace dss
