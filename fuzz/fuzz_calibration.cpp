// Calibration YAML (dss calibrate's output, read by dss eval and
// calibration_node). An accepted calibration must survive its round trip.
#include <cstdlib>

#include "digital_sun_sensor/baseline/calibration.h"
#include "fuzz_entry.h"

extern "C" int DSS_FUZZ_ENTRY(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  dss::Calibration calibration;
  try {
    calibration = dss::parseCalibration(text, "fuzz.calib.yaml");
  } catch (const dss::CalibrationError&) {
    return 0;
  }
  try {
    dss::parseCalibration(dss::toYaml(calibration), "round trip");
  } catch (const dss::CalibrationError&) {
    std::abort();
  }
  return 0;
}
