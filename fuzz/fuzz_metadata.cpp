// Model metadata YAML (the first section of a model file), with what is read
// from it later: the sensor it embeds and its compatibility check.
#include "digital_sun_sensor/model/metadata.h"
#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/sim/sensor_config.h"
#include "fuzz_entry.h"

extern "C" int DSS_FUZZ_ENTRY(const std::uint8_t* data, std::size_t size) {
  static const dss::SensorConfig sensor =
      dss::loadSensorConfig(dss::fuzz::sourceDir() + "/config/sensors/thesis_sa.yaml");
  const std::string text(reinterpret_cast<const char*>(data), size);
  try {
    const dss::ModelMetadata meta = dss::metadataFromYaml(text, "fuzz metadata");
    dss::checkSensorCompatible(meta, sensor, "fuzz metadata");
    dss::metadataFromYaml(dss::metadataToYaml(meta), "round trip");
  } catch (const dss::ModelError&) {
  }
  return 0;
}
