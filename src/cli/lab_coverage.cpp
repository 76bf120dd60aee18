#include "lab_coverage.h"

#include <iostream>

namespace dss::cli {
namespace {

// 25 uniform draws leave one of the ninths empty about half the time, a
// spread plan of 25 (dss generate --sampling spread) never.
constexpr int kLabCoverageCellsPerSide = 3;

}  // namespace

FieldCoverage noteLabCoverage(const SensorConfig& sensor, const std::vector<double>& alpha_rad,
                              const std::vector<double>& beta_rad) {
  const FieldCoverage coverage = measureFieldCoverage(sensor, alpha_rad, beta_rad, kLabCoverageCellsPerSide);
  if (coverage.emptyCells() > 0)
    std::cerr << "note: the " << alpha_rad.size() << " lab images leave " << coverage.emptyCells() << " of "
              << coverage.counts.size()
              << " parts of the field of view (its 3 x 3 partition in alpha and beta) without an image; the "
                 "calibration rests there on the rest of the field. Lab points spread over the field cover it (as "
                 "dss generate --sampling spread draws them)\n";
  return coverage;
}

}  // namespace dss::cli
