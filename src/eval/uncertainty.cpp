#include "digital_sun_sensor/eval/uncertainty.h"

#include <cmath>
#include <limits>

#include "digital_sun_sensor/common/statistics.h"

namespace dss {
namespace {

constexpr double kOneSigmaFraction = 0.682689492137;

double standardized(const ErrorAndSigma& s) {
  return s.sigma_rad > 0.0 && std::isfinite(s.sigma_rad) ? std::abs(s.error_rad) / s.sigma_rad
                                                         : std::numeric_limits<double>::infinity();
}

}  // namespace

Coverage measureCoverage(const std::vector<ErrorAndSigma>& samples) {
  Coverage c;
  c.count = samples.size();
  if (samples.empty()) return c;
  for (const auto& s : samples) {
    const double z = standardized(s);
    for (int k = 0; k < 3; ++k) c.within[k] += z <= k + 1.0;
  }
  for (double& w : c.within) w /= static_cast<double>(samples.size());
  return c;
}

double sigmaScaleForCoverage(const std::vector<ErrorAndSigma>& samples) {
  if (samples.empty()) return 1.0;
  std::vector<double> z;
  z.reserve(samples.size());
  for (const auto& s : samples) z.push_back(standardized(s));
  const double scale = percentile(z, kOneSigmaFraction);
  return std::isfinite(scale) && scale > 0.0 ? scale : 1.0;
}

}  // namespace dss
