#include "digital_sun_sensor/sim/sensor_config.h"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <sstream>

#include "digital_sun_sensor/common/file_io.h"
#include "digital_sun_sensor/common/limits.h"
#include "digital_sun_sensor/common/yaml_reader.h"
#include "sensor_config_fields.h"

namespace dss {
namespace {

// "a.b.c=value": replaces (or creates) that scalar; the value is parsed as YAML.
void applyOverride(YAML::Node& root, const std::string& spec, const std::string& origin) {
  auto eq = spec.find('=');
  if (eq == std::string::npos || eq == 0) {
    throw ConfigError(origin + ": override '" + spec + "': expected key.path=value");
  }
  std::string path = spec.substr(0, eq);
  YAML::Node value;
  try {
    value = loadYaml(spec.substr(eq + 1), origin + ": override '" + spec + "'");
  } catch (const YamlError& e) {
    throw ConfigError(e.what());
  } catch (const YAML::Exception& e) {
    throw ConfigError(origin + ": override '" + spec + "': value is not valid YAML");
  }
  std::vector<std::string> keys;
  std::stringstream ss(path);
  for (std::string k; std::getline(ss, k, '.');) keys.push_back(k);
  // yaml-cpp nodes are handles: walk with fresh handles, never reassign one.
  std::vector<YAML::Node> chain{root};
  for (std::size_t i = 0; i + 1 < keys.size(); ++i) {
    YAML::Node next = chain.back()[keys[i]];
    if (next.IsDefined() && !next.IsNull() && !next.IsMap()) {
      throw ConfigError(origin + ": override '" + spec + "': '" + keys[i] + "' is not a mapping");
    }
    chain.push_back(next);
  }
  chain.back()[keys.back()] = value;
}

}  // namespace

int SensorConfig::numSubFovClasses() const {
  return subfov == SubFovType::kQuadrant ? 4 : static_cast<int>(mask.apertures.size());
}

SensorConfig parseSensorConfig(const std::string& yaml_text, const std::string& origin,
                               const std::vector<std::string>& overrides) {
  YAML::Node root;
  try {
    root = loadYaml(yaml_text, origin);
  } catch (const YamlError& e) {
    throw ConfigError(e.what());
  } catch (const YAML::ParserException& e) {
    throw ConfigError(origin + ": malformed YAML at line " + std::to_string(e.mark.line + 1) + ", column " +
                      std::to_string(e.mark.column + 1) + ": " + e.msg);
  }
  if (!root.IsMap()) throw ConfigError(origin + ": expected a YAML mapping at the top level");
  for (const auto& o : overrides) applyOverride(root, o, origin);
  try {
    SensorConfig config;
    config.source_path = origin;
    YamlFieldReader fields{YamlReader(root, origin)};
    sensorConfigFields(fields, config);
    fields.rejectUnknownKeys();  // a misspelt key or --set path is an error, not a default
    return config;
  } catch (const YamlError& e) {
    throw ConfigError(e.what());
  }
}

double DetectorNoiseConfig::darkCurrentAtTemperatureEPerS() const {
  return dark_current_e_per_s * std::pow(2.0, (temperature_c - dark_reference_temp_c) / dark_doubling_temp_c);
}

AsBuiltConfig asBuiltTolerances(double scale) {
  AsBuiltConfig ab;
  ab.height_sigma_um = 20.0 * scale;
  ab.offset_sigma_um = 10.0 * scale;
  ab.rotation_sigma_deg = 0.2 * scale;
  ab.tilt_sigma_deg = 0.1 * scale;
  ab.aperture_position_sigma_um = 1.0 * scale;
  ab.aperture_diameter_sigma_um = 1.0 * scale;
  return ab;
}

SensorConfig loadSensorConfig(const std::string& path, const std::vector<std::string>& overrides) {
  std::string text;
  try {
    text = readFile(path, limits::kMaxYamlFileBytes);
  } catch (const std::runtime_error& e) {
    throw ConfigError(std::string("cannot read sensor config: ") + e.what());
  }
  return parseSensorConfig(text, path, overrides);
}

std::string toYaml(const SensorConfig& config) {
  YamlFieldWriter fields;
  SensorConfig copy = config;  // the table takes its values by reference
  sensorConfigFields(fields, copy);
  return fields.str();
}

}  // namespace dss

namespace dss {

std::string sensorDesignMismatch(const SensorConfig& made_for, const SensorConfig& config) {
  std::ostringstream o;
  auto mismatch = [&](const std::string& key, auto made_for_value, auto config_value) {
    o << "sensor '" << made_for.name << "' with " << key << " = " << made_for_value << ", but sensor '" << config.name
      << "' has " << config_value;
    return o.str();
  };
  auto differs = [](double a, double b, double rel) {
    return std::abs(a - b) > rel * std::max(std::abs(a), std::abs(b));
  };
  if (made_for.detector.width_px != config.detector.width_px)
    return mismatch("detector.width_px", made_for.detector.width_px, config.detector.width_px);
  if (made_for.detector.height_px != config.detector.height_px)
    return mismatch("detector.height_px", made_for.detector.height_px, config.detector.height_px);
  if (differs(made_for.detector.pitch_um, config.detector.pitch_um, 1e-6))
    return mismatch("detector.pitch_um", made_for.detector.pitch_um, config.detector.pitch_um);
  if (made_for.noise.bit_depth != config.noise.bit_depth)
    return mismatch("noise.bit_depth", made_for.noise.bit_depth, config.noise.bit_depth);
  if (made_for.threshold.enabled != config.threshold.enabled)
    return mismatch("threshold.enabled", made_for.threshold.enabled, config.threshold.enabled);
  // Within as-built tolerances the same design; beyond 1% another sensor.
  if (differs(made_for.mask.height_mm, config.mask.height_mm, 0.01))
    return mismatch("mask.height_mm", made_for.mask.height_mm, config.mask.height_mm);
  if (made_for.mask.apertures.size() != config.mask.apertures.size())
    return mismatch("the number of apertures", made_for.mask.apertures.size(), config.mask.apertures.size());
  for (std::size_t i = 0; i < config.mask.apertures.size(); ++i) {
    const auto &a = made_for.mask.apertures[i], &b = config.mask.apertures[i];
    if (std::hypot(a.x_um - b.x_um, a.y_um - b.y_um) > 1.0)
      return mismatch("aperture " + std::to_string(i) + " position (um)",
                      "(" + std::to_string(a.x_um) + ", " + std::to_string(a.y_um) + ")",
                      "(" + std::to_string(b.x_um) + ", " + std::to_string(b.y_um) + ")");
  }
  if (made_for.cover_glass.enabled != config.cover_glass.enabled)
    return mismatch("cover_glass.enabled", made_for.cover_glass.enabled, config.cover_glass.enabled);
  if (made_for.numSubFovClasses() != config.numSubFovClasses())
    return mismatch("sub-FOV classes", made_for.numSubFovClasses(), config.numSubFovClasses());
  return "";
}

}  // namespace dss
