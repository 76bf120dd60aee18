// Small summary statistics shared by the benchmarks and the nodes' diagnostics.
#pragma once

#include <algorithm>
#include <vector>

namespace dss {

// Linearly interpolated q-quantile (q in [0, 1]) of `values`; 0 when empty.
inline double percentile(std::vector<double> values, double q) {
  if (values.empty()) return 0.0;
  std::sort(values.begin(), values.end());
  const double pos = q * static_cast<double>(values.size() - 1);
  const auto lo = static_cast<std::size_t>(pos);
  const auto hi = std::min(lo + 1, values.size() - 1);
  return values[lo] + (pos - static_cast<double>(lo)) * (values[hi] - values[lo]);
}

}  // namespace dss
