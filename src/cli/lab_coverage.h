// How a calibration's lab images cover the field of view (dss calibrate,
// dss calibrate-unit): measured on the field's 3 x 3 partition in alpha and
// beta, with a note on stderr when a part holds no image.
#pragma once

#include <vector>

#include "digital_sun_sensor/sim/field_coverage.h"
#include "digital_sun_sensor/sim/sensor_config.h"

namespace dss::cli {

FieldCoverage noteLabCoverage(const SensorConfig& sensor, const std::vector<double>& alpha_rad,
                              const std::vector<double>& beta_rad);

}  // namespace dss::cli
