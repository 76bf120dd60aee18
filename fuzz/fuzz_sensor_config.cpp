// Sensor config YAML and --set overrides: input "<yaml>\0<override>\0<override>...".
// An accepted config must also survive the round trip through toYaml.
#include <cstdlib>

#include "digital_sun_sensor/sim/sensor_config.h"
#include "fuzz_entry.h"

extern "C" int DSS_FUZZ_ENTRY(const std::uint8_t* data, std::size_t size) {
  const auto parts = dss::fuzz::splitAtNul(data, size, 8);
  const std::vector<std::string> overrides(parts.begin() + 1, parts.end());
  dss::SensorConfig config;
  try {
    config = dss::parseSensorConfig(parts[0], "fuzz.yaml", overrides);
  } catch (const dss::ConfigError&) {
    return 0;
  }
  try {
    dss::parseSensorConfig(dss::toYaml(config), "round trip");
  } catch (const dss::ConfigError&) {
    std::abort();  // an accepted config that its own writer cannot express
  }
  return 0;
}
