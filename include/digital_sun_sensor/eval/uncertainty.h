// Honesty of predicted uncertainty: how often the error lies within k predicted
// standard deviations (ideal for a Gaussian: 68.27 / 95.45 / 99.73 % at
// k = 1 / 2 / 3), and the per-axis factor on the predicted sigma that makes the
// 1-sigma coverage exact on a calibration set.
#pragma once

#include <array>
#include <cstddef>
#include <vector>

namespace dss {

struct ErrorAndSigma {
  double error_rad;  // estimate - truth
  double sigma_rad;  // predicted standard deviation
};

struct Coverage {
  std::size_t count = 0;
  std::array<double, 3> within{};  // fraction with |error| <= k sigma, k = 1, 2, 3
};

// Samples with a non-finite or non-positive sigma count as outside.
Coverage measureCoverage(const std::vector<ErrorAndSigma>& samples);

// The factor f such that |error| <= f * sigma for 68.27 % of the samples
// (the 68.27 % quantile of |error| / sigma); 1 when there are no samples.
double sigmaScaleForCoverage(const std::vector<ErrorAndSigma>& samples);

}  // namespace dss
