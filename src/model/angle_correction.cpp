#include "digital_sun_sensor/model/angle_correction.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <utility>

namespace dss {
namespace {

// P_0..P_degree at x (Bonnet's recursion).
std::vector<double> legendre(int degree, double x) {
  std::vector<double> p(static_cast<std::size_t>(degree) + 1, 1.0);
  if (degree >= 1) p[1] = x;
  for (int n = 1; n < degree; ++n) p[n + 1] = ((2.0 * n + 1.0) * x * p[n] - n * p[n - 1]) / (n + 1.0);
  return p;
}

}  // namespace

std::size_t AngleCorrection::termCount(int degree) {
  return degree < 0 ? 0 : static_cast<std::size_t>((degree + 1) * (degree + 2) / 2);
}

std::vector<double> AngleCorrection::terms(int degree, double a, double b) {
  std::vector<double> out;
  if (degree < 0) return out;
  out.reserve(termCount(degree));
  const auto pa = legendre(degree, std::clamp(a, -1.0, 1.0));
  const auto pb = legendre(degree, std::clamp(b, -1.0, 1.0));
  for (int total = 0; total <= degree; ++total)
    for (int j = 0; j <= total; ++j) out.push_back(pa[total - j] * pb[j]);
  return out;
}

std::array<double, 2> AngleCorrection::bias(double a, double b) const {
  std::array<double, 2> out{0.0, 0.0};
  if (!active()) return out;
  const auto t = terms(degree, a, b);
  for (std::size_t k = 0; k < t.size(); ++k) {
    out[0] += alpha[k] * t[k];
    out[1] += beta[k] * t[k];
  }
  return out;
}

void AngleCorrection::validate() const {
  if (degree < kNone || degree > kMaxDegree)
    throw std::invalid_argument("angle correction degree " + std::to_string(degree) + " is outside " +
                                std::to_string(kNone) + ".." + std::to_string(kMaxDegree));
  const std::size_t n = termCount(degree);
  if (alpha.size() != n || beta.size() != n)
    throw std::invalid_argument("angle correction of degree " + std::to_string(degree) + " needs " + std::to_string(n) +
                                " coefficients per axis, not " + std::to_string(alpha.size()) + " / " +
                                std::to_string(beta.size()));
  for (const auto* c : {&alpha, &beta})
    for (double v : *c)
      if (!std::isfinite(v)) throw std::invalid_argument("angle correction has a non-finite coefficient");
}

void HeightCorrection::validate() const {
  if (!std::isfinite(height_change_um) || height_change_um == 0.0)
    throw std::invalid_argument("height correction: the height change must be finite and non-zero");
  change.validate();
}

std::vector<std::pair<int, double>> heightInterpolation(const std::vector<double>& entry_changes_um,
                                                        double height_change_um) {
  // The entries on this side, nearest the design first, after the design's own (0, -1).
  std::vector<std::pair<double, int>> side{{0.0, -1}};
  for (std::size_t k = 0; k < entry_changes_um.size(); ++k)
    if (height_change_um * entry_changes_um[k] > 0.0)
      side.emplace_back(std::abs(entry_changes_um[k]), static_cast<int>(k));
  if (side.size() < 2) return {};
  std::sort(side.begin(), side.end());
  const double distance = std::abs(height_change_um);
  std::size_t upper = 1;
  while (upper + 1 < side.size() && side[upper].first < distance) ++upper;
  const double t = (distance - side[upper - 1].first) / (side[upper].first - side[upper - 1].first);
  return {{side[upper - 1].second, 1.0 - t}, {side[upper].second, t}};
}

UnitAngleCorrection::UnitAngleCorrection(const AngleCorrection& design, const std::vector<HeightCorrection>& by_height,
                                         double height_change_um)
    : design_(design) {
  std::vector<const AngleCorrection*> changes;
  std::vector<double> heights;
  for (const HeightCorrection& h : by_height)
    if (h.change.active()) changes.push_back(&h.change), heights.push_back(h.height_change_um);
  const auto terms = heightInterpolation(heights, height_change_um);
  for (std::size_t k = 0; k < terms.size(); ++k) {
    changes_[k] = terms[k].first < 0 ? nullptr : changes[static_cast<std::size_t>(terms[k].first)];
    weights_[k] = terms[k].second;
  }
}

std::array<double, 2> UnitAngleCorrection::bias(double a, double b) const {
  std::array<double, 2> out = design_.bias(a, b);
  for (std::size_t k = 0; k < 2; ++k) {
    if (!changes_[k]) continue;
    const std::array<double, 2> change = changes_[k]->bias(a, b);
    out[0] += weights_[k] * change[0];
    out[1] += weights_[k] * change[1];
  }
  return out;
}

}  // namespace dss
