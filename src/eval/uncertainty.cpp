#include "digital_sun_sensor/eval/uncertainty.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

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

double SiteSigmaLaw::factor(double sites) const {
  return active() && sites > 0.0 ? std::pow(sites / reference_sites, -exponent) : 1.0;
}

SiteSigmaLaw fitSiteSigmaLaw(const std::vector<std::vector<SitedError>>& groups) {
  constexpr int kQuarters = 4;
  std::vector<double> all_sites;
  for (const auto& g : groups) {
    if (g.size() < 10 * kQuarters) return {};
    for (const auto& s : g) all_sites.push_back(s.sites);
  }
  if (all_sites.empty()) return {};
  SiteSigmaLaw candidate{0.0, percentile(all_sites, 0.5)};
  if (!(candidate.reference_sites > 0.0)) return {};
  // Each group's samples in order of lit sites, cut into quarters.
  std::vector<std::vector<std::size_t>> order(groups.size());
  for (std::size_t g = 0; g < groups.size(); ++g) {
    order[g].resize(groups[g].size());
    std::iota(order[g].begin(), order[g].end(), 0);
    std::stable_sort(order[g].begin(), order[g].end(),
                     [&](std::size_t a, std::size_t b) { return groups[g][a].sites < groups[g][b].sites; });
  }
  auto miss = [&](const SiteSigmaLaw& law) {
    double total = 0.0;
    for (std::size_t g = 0; g < groups.size(); ++g) {
      std::vector<ErrorAndSigma> z;
      for (const auto& s : groups[g]) z.push_back({s.error_rad, law.factor(s.sites)});
      const double scale = sigmaScaleForCoverage(z);
      for (auto& s : z) s.sigma_rad *= scale;
      const std::size_t n = z.size();
      for (int q = 0; q < kQuarters; ++q) {
        std::vector<ErrorAndSigma> quarter;
        for (std::size_t k = n * q / kQuarters; k < n * (q + 1) / kQuarters; ++k) quarter.push_back(z[order[g][k]]);
        total += std::abs(measureCoverage(quarter).within[0] - kOneSigmaFraction);
      }
    }
    return total;
  };
  SiteSigmaLaw best = candidate;
  double best_miss = miss(best);
  for (int step = 1; step <= 60; ++step) {  // by |exponent|: 0.05 .. 3, and -0.05 .. -0.5
    for (const double exponent : {0.05 * step, -0.05 * step}) {
      if (exponent < -0.5 - 1e-9) continue;
      candidate.exponent = exponent;
      const double m = miss(candidate);
      if (m < best_miss - 1e-12) {
        best = candidate;
        best_miss = m;
      }
    }
  }
  if (best.exponent == 0.0) best.reference_sites = 0.0;
  return best;
}

}  // namespace dss
