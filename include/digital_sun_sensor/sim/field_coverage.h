// How evenly a set of sun directions covers a sensor's field of view: the
// count in each cell of a k x k partition of the field (alpha, beta). A unit
// calibrated on lab images that leave a part of the field empty rests there
// on its fit elsewhere; `dss calibrate-unit` reports it. Torch-free.
#pragma once

#include <vector>

#include "digital_sun_sensor/sim/sensor_config.h"

namespace dss {

struct FieldCoverage {
  std::vector<int> counts;  // row-major, beta rows by alpha columns; directions outside the field are not counted

  int emptyCells() const;
  int leastCount() const;
};

// Throws std::invalid_argument when cells_per_side < 1.
FieldCoverage measureFieldCoverage(const SensorConfig& config, const std::vector<double>& alpha_rad,
                                   const std::vector<double>& beta_rad, int cells_per_side);

}  // namespace dss
