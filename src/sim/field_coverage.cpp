#include "digital_sun_sensor/sim/field_coverage.h"

#include <algorithm>
#include <stdexcept>
#include <string>

#include "digital_sun_sensor/common/units.h"

namespace dss {

int FieldCoverage::emptyCells() const { return static_cast<int>(std::count(counts.begin(), counts.end(), 0)); }

int FieldCoverage::leastCount() const { return counts.empty() ? 0 : *std::min_element(counts.begin(), counts.end()); }

FieldCoverage measureFieldCoverage(const SensorConfig& config, const std::vector<double>& alpha_rad,
                                   const std::vector<double>& beta_rad, int cells_per_side) {
  if (cells_per_side < 1) throw std::invalid_argument("field coverage: cells_per_side must be >= 1");
  if (alpha_rad.size() != beta_rad.size())
    throw std::invalid_argument("field coverage: " + std::to_string(alpha_rad.size()) + " alphas for " +
                                std::to_string(beta_rad.size()) + " betas");
  FieldCoverage coverage;
  coverage.counts.assign(static_cast<std::size_t>(cells_per_side) * cells_per_side, 0);
  const double alpha_max = degToRad(config.fov.alpha_max_deg), beta_max = degToRad(config.fov.beta_max_deg);
  auto cell = [&](double angle, double max) {  // -1: outside the field
    const double u = (angle / max + 1.0) / 2.0;
    if (!(u >= 0.0 && u <= 1.0)) return -1;
    return std::min(cells_per_side - 1, static_cast<int>(u * cells_per_side));
  };
  for (std::size_t i = 0; i < alpha_rad.size(); ++i) {
    const int col = cell(alpha_rad[i], alpha_max), row = cell(beta_rad[i], beta_max);
    if (col >= 0 && row >= 0) ++coverage.counts[static_cast<std::size_t>(row) * cells_per_side + col];
  }
  return coverage;
}

}  // namespace dss
