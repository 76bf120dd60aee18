#include "digital_sun_sensor/model/angle_correction.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

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

}  // namespace dss
