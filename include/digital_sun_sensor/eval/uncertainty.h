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

// A sigma that follows the image's lit-site count n: the fitted sigma times
// (n / reference_sites)^-exponent. A spot's centroid averages n pixels, so its
// noise falls with n (exponent 0.5 for independent pixels); stray light lifts
// the spot's skirt over the threshold and adds pixels, so one constant sigma
// over-covers stray-lit images and under-covers nominal ones.
struct SiteSigmaLaw {
  double exponent = 0.0;
  double reference_sites = 0.0;  // 0: no scaling
  bool active() const { return exponent != 0.0 && reference_sites > 0.0; }
  // The factor on sigma for an image of `sites` lit sites (1 when inactive or sites <= 0).
  double factor(double sites) const;
};

struct SitedError {
  double error_rad;
  int sites;  // lit sites of the image
};

// The exponent (-0.5 to 3 in steps of 0.05) whose law, scaled per group
// for 68.27 % coverage over the group, covers each quarter of the group's
// samples by lit-site count closest to 68.27 % at 1 sigma (summed absolute
// misses over groups and quarters; ties go to the smaller |exponent|);
// reference_sites: the median count of all samples. Groups are fitted with
// one sigma each (the axes, or one group for both). Inactive when there are
// fewer than 40 samples in a group.
SiteSigmaLaw fitSiteSigmaLaw(const std::vector<std::vector<SitedError>>& groups);

}  // namespace dss
