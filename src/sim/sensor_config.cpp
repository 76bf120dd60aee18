#include "digital_sun_sensor/sim/sensor_config.h"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <sstream>

#include "digital_sun_sensor/common/file_io.h"
#include "digital_sun_sensor/common/limits.h"
#include "digital_sun_sensor/common/yaml_reader.h"

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

DetectorConfig readDetector(const YamlReader& r) {
  DetectorConfig d;
  d.width_px = r.get<int>("width_px");
  d.height_px = r.get<int>("height_px");
  const std::string side_range = "must be in [8, " + std::to_string(limits::kMaxDetectorSidePx) + "] (limit)";
  if (d.width_px < 8 || d.width_px > limits::kMaxDetectorSidePx) r.fail("width_px", side_range);
  if (d.height_px < 8 || d.height_px > limits::kMaxDetectorSidePx) r.fail("height_px", side_range);
  d.pitch_um = r.positive("pitch_um");
  return d;
}

ApertureConfig readAperture(const YamlReader& r) {
  ApertureConfig a;
  a.x_um = r.get<double>("x_um", 0.0);
  a.y_um = r.get<double>("y_um", 0.0);
  auto shape = r.get<std::string>("shape", "circle");
  if (shape == "circle") {
    a.shape = ApertureShape::kCircle;
    a.diameter_um = r.positive("diameter_um");
  } else if (shape == "rectangle" || shape == "square") {
    a.shape = ApertureShape::kRectangle;
    if (shape == "square") {
      a.width_um = a.height_um = r.positive("side_um");
    } else {
      a.width_um = r.positive("width_um");
      a.height_um = r.positive("height_um");
    }
    a.rotation_deg = r.get<double>("rotation_deg", 0.0);
  } else {
    r.fail("shape", "unknown aperture shape '" + shape + "' (expected circle, square or rectangle)");
  }
  return a;
}

MaskConfig readMask(const YamlReader& r) {
  MaskConfig m;
  m.height_mm = r.positive("height_mm");
  m.thickness_mm = r.nonNegative("thickness_mm", 0.0);
  if (!r.has("apertures")) r.fail("apertures", "missing required key");
  const YAML::Node& list = r.node()["apertures"];
  if (!list.IsSequence() || list.size() == 0) r.fail("apertures", "expected a non-empty list of apertures");
  if (list.size() > limits::kMaxApertures)
    r.fail("apertures",
           std::to_string(list.size()) + " apertures, over the limit of " + std::to_string(limits::kMaxApertures));
  for (std::size_t i = 0; i < list.size(); ++i) {
    m.apertures.push_back(readAperture(r.item("apertures", i)));
  }
  return m;
}

OpticsConfig readOptics(const YamlReader& r) {
  OpticsConfig o;
  auto mode = r.get<std::string>("mode", "fresnel");
  if (mode == "fresnel") {
    o.mode = OpticsMode::kFresnel;
  } else if (mode == "far_field") {
    o.mode = OpticsMode::kFarField;
  } else {
    r.fail("mode", "unknown optics mode '" + mode + "' (expected fresnel or far_field)");
  }
  o.wavelengths_um = r.positiveList("wavelengths_um");
  if (o.wavelengths_um.size() > static_cast<std::size_t>(limits::kMaxWavelengths))
    r.fail("wavelengths_um", std::to_string(o.wavelengths_um.size()) + " wavelengths, over the limit of " +
                                 std::to_string(limits::kMaxWavelengths));
  o.spectral_weights = r.positiveList("spectral_weights");
  if (o.spectral_weights.size() != o.wavelengths_um.size()) {
    r.fail("spectral_weights", "needs one weight per wavelength (" + std::to_string(o.wavelengths_um.size()) +
                                   "), got " + std::to_string(o.spectral_weights.size()));
  }
  for (std::size_t i = 0; i < o.wavelengths_um.size(); ++i) {
    if (o.wavelengths_um[i] > 20.0) r.fail("wavelengths_um", "wavelengths are in micrometres (got > 20)");
  }
  YamlReader sun = r.child("sun_disk", false);
  o.sun.enabled = sun.get<bool>("enabled", true);
  o.sun.angular_diameter_deg = sun.positive("angular_diameter_deg", 0.533);
  o.sun.limb_darkening_u = sun.fraction("limb_darkening_u", 0.56);
  o.vignetting = r.get<bool>("vignetting", true);
  o.grid_step_um = r.positive("grid_step_um", 1.0);
  o.grid_size = r.get<int>("grid_size", 512);
  if (o.grid_size < 32 || o.grid_size > limits::kMaxDiffractionGrid || (o.grid_size & (o.grid_size - 1)) != 0) {
    r.fail("grid_size", "must be a power of two in [32, " + std::to_string(limits::kMaxDiffractionGrid) + "] (limit)");
  }
  o.psf_node_step_deg = r.positive("psf_node_step_deg", 1.0);
  return o;
}

DetectorNoiseConfig readNoise(const YamlReader& r) {
  DetectorNoiseConfig n;
  n.shot_noise = r.get<bool>("shot_noise", true);
  n.read_noise_e = r.nonNegative("read_noise_e", 3.0);
  n.full_well_e = r.positive("full_well_e");
  n.adc_full_scale_e = r.positive("adc_full_scale_e", n.full_well_e);
  n.bit_depth = r.get<int>("bit_depth", 8);
  if (n.bit_depth < 1 || n.bit_depth > 16) r.fail("bit_depth", "must be in [1, 16]");
  n.black_level_dn = r.nonNegative("black_level_dn", 0.0);
  n.dark_current_e_per_s = r.nonNegative("dark_current_e_per_s", 0.0);
  n.dark_reference_temp_c = r.get<double>("dark_reference_temp_c", 25.0);
  n.dark_doubling_temp_c = r.positive("dark_doubling_temp_c", 6.5);
  n.temperature_c = r.get<double>("temperature_c", 25.0);
  if (n.temperature_c < -273.15) r.fail("temperature_c", "below absolute zero");
  n.dsnu_fraction = r.nonNegative("dsnu_fraction", 0.0);
  n.prnu_fraction = r.nonNegative("prnu_fraction", 0.0);
  return n;
}

}  // namespace

int SensorConfig::numSubFovClasses() const {
  return subfov == SubFovType::kQuadrant ? 4 : static_cast<int>(mask.apertures.size());
}

namespace {
SensorConfig readSensorConfig(const YamlReader& r);
}  // namespace

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
    return readSensorConfig(YamlReader(root, origin));
  } catch (const YamlError& e) {
    throw ConfigError(e.what());
  }
}

namespace {

SensorConfig readSensorConfig(const YamlReader& r) {
  SensorConfig c;
  c.source_path = r.origin();
  c.name = r.get<std::string>("name");
  c.detector = readDetector(r.child("detector"));
  c.mask = readMask(r.child("mask"));

  YamlReader glass = r.child("cover_glass", false);
  c.cover_glass.enabled = glass.get<bool>("enabled", false);
  c.cover_glass.thickness_mm = glass.nonNegative("thickness_mm", 0.0);
  c.cover_glass.refractive_index = glass.get<double>("refractive_index", 1.5);
  if (c.cover_glass.refractive_index < 1.0) glass.fail("refractive_index", "must be >= 1");
  if (c.cover_glass.enabled && c.cover_glass.thickness_mm > c.mask.height_mm) {
    glass.fail("thickness_mm", "cover glass is thicker than the mask height");
  }

  c.optics = readOptics(r.child("optics"));

  YamlReader rad = r.child("radiometry", false);
  c.radiometry.irradiance_w_m2 = rad.positive("irradiance_w_m2", 1361.0);
  c.radiometry.nd_transmission = rad.positive("nd_transmission", 1e-3);
  c.radiometry.quantum_efficiency = rad.positive("quantum_efficiency", 0.5);
  if (c.radiometry.quantum_efficiency > 1.0) rad.fail("quantum_efficiency", "must be <= 1");

  YamlReader exp = r.child("exposure", false);
  auto exp_mode = exp.get<std::string>("mode", "auto");
  if (exp_mode == "auto") {
    c.exposure.mode = ExposureMode::kAuto;
  } else if (exp_mode == "fixed") {
    c.exposure.mode = ExposureMode::kFixed;
  } else {
    exp.fail("mode", "unknown exposure mode '" + exp_mode + "' (expected auto or fixed)");
  }
  c.exposure.peak_fraction_of_full_well = exp.positive("peak_fraction_of_full_well", 1.0);
  c.exposure.exposure_s = exp.positive("exposure_s", 1e-3);

  c.noise = readNoise(r.child("detector_noise"));

  YamlReader thr = r.child("threshold", false);
  c.threshold.enabled = thr.get<bool>("enabled", false);
  c.threshold.level_fraction = thr.fraction("level_fraction", 0.9);
  c.threshold.rescale = thr.get<bool>("rescale", true);
  if (c.threshold.level_fraction >= 1.0) thr.fail("level_fraction", "must be < 1");

  YamlReader ab = r.child("as_built", false);
  c.as_built.height_sigma_um = ab.nonNegative("height_sigma_um", 0.0);
  c.as_built.offset_sigma_um = ab.nonNegative("offset_sigma_um", 0.0);
  c.as_built.rotation_sigma_deg = ab.nonNegative("rotation_sigma_deg", 0.0);
  c.as_built.tilt_sigma_deg = ab.nonNegative("tilt_sigma_deg", 0.0);
  c.as_built.aperture_position_sigma_um = ab.nonNegative("aperture_position_sigma_um", 0.0);
  c.as_built.aperture_diameter_sigma_um = ab.nonNegative("aperture_diameter_sigma_um", 0.0);

  YamlReader an = r.child("anomalies", false);
  YamlReader stray = an.child("stray_light", false);
  c.anomalies.stray_light_probability = stray.fraction("probability", 0.0);
  c.anomalies.stray_light_max_fraction = stray.nonNegative("max_fraction", 0.2);
  YamlReader hot = an.child("hot_pixels", false);
  c.anomalies.hot_pixel_count = hot.get<int>("count", 0);
  if (c.anomalies.hot_pixel_count < 0 ||
      c.anomalies.hot_pixel_count > std::int64_t{c.detector.width_px} * c.detector.height_px)
    hot.fail("count", "must be in [0, the detector's pixel count]");
  c.anomalies.hot_pixel_min_e_per_s = hot.positive("min_e_per_s", 1e5);
  c.anomalies.hot_pixel_max_e_per_s = hot.positive("max_e_per_s", 1e7);
  if (c.anomalies.hot_pixel_max_e_per_s < c.anomalies.hot_pixel_min_e_per_s) {
    hot.fail("max_e_per_s", "must be >= min_e_per_s");
  }
  YamlReader debris = an.child("debris", false);
  c.anomalies.debris_probability = debris.fraction("probability", 0.0);
  c.anomalies.debris_max_blocked_fraction = debris.fraction("max_blocked_fraction", 0.3);
  YamlReader ghost = an.child("ghost", false);
  c.anomalies.ghost_probability = ghost.fraction("probability", 0.0);
  c.anomalies.ghost_reflectance = ghost.fraction("reflectance", 0.02);

  YamlReader fov = r.child("fov");
  c.fov.alpha_max_deg = fov.positive("alpha_max_deg");
  c.fov.beta_max_deg = fov.positive("beta_max_deg");
  if (c.fov.alpha_max_deg >= 89.0 || c.fov.beta_max_deg >= 89.0) fov.fail("alpha_max_deg", "must be < 89");
  if (c.optics.mode == OpticsMode::kFresnel) {
    // The simulator caches a diffraction pattern per node over the field.
    const double step = c.optics.psf_node_step_deg;
    const double nodes = (2.0 * c.fov.alpha_max_deg / step + 2.0) * (2.0 * c.fov.beta_max_deg / step + 2.0);
    if (nodes > static_cast<double>(limits::kMaxPsfNodes))
      r.child("optics").fail("psf_node_step_deg", std::to_string(step) + " deg gives " +
                                                      std::to_string(static_cast<long long>(nodes)) +
                                                      " diffraction nodes over the field of view, over the limit of " +
                                                      std::to_string(limits::kMaxPsfNodes));
  }

  auto subfov = r.get<std::string>("subfov", "quadrant");
  if (subfov == "quadrant") {
    c.subfov = SubFovType::kQuadrant;
  } else if (subfov == "nearest_aperture") {
    c.subfov = SubFovType::kNearestAperture;
  } else {
    r.fail("subfov", "unknown sub-FOV scheme '" + subfov + "' (expected quadrant or nearest_aperture)");
  }
  r.rejectUnknownKeys();  // a misspelt key or --set path is an error, not a default
  return c;
}

}  // namespace

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

std::string toYaml(const SensorConfig& c) {
  YAML::Emitter e;
  e << YAML::BeginMap;
  e << YAML::Key << "name" << YAML::Value << c.name;
  e << YAML::Key << "detector" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key << "width_px" << YAML::Value
    << c.detector.width_px << YAML::Key << "height_px" << YAML::Value << c.detector.height_px << YAML::Key << "pitch_um"
    << YAML::Value << c.detector.pitch_um << YAML::EndMap;
  e << YAML::Key << "mask" << YAML::Value << YAML::BeginMap;
  e << YAML::Key << "height_mm" << YAML::Value << c.mask.height_mm;
  e << YAML::Key << "thickness_mm" << YAML::Value << c.mask.thickness_mm;
  e << YAML::Key << "apertures" << YAML::Value << YAML::BeginSeq;
  for (const auto& a : c.mask.apertures) {
    e << YAML::Flow << YAML::BeginMap << YAML::Key << "x_um" << YAML::Value << a.x_um << YAML::Key << "y_um"
      << YAML::Value << a.y_um;
    if (a.shape == ApertureShape::kCircle) {
      e << YAML::Key << "shape" << YAML::Value << "circle" << YAML::Key << "diameter_um" << YAML::Value
        << a.diameter_um;
    } else {
      e << YAML::Key << "shape" << YAML::Value << "rectangle" << YAML::Key << "width_um" << YAML::Value << a.width_um
        << YAML::Key << "height_um" << YAML::Value << a.height_um << YAML::Key << "rotation_deg" << YAML::Value
        << a.rotation_deg;
    }
    e << YAML::EndMap;
  }
  e << YAML::EndSeq << YAML::EndMap;
  e << YAML::Key << "cover_glass" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key << "enabled"
    << YAML::Value << c.cover_glass.enabled << YAML::Key << "thickness_mm" << YAML::Value << c.cover_glass.thickness_mm
    << YAML::Key << "refractive_index" << YAML::Value << c.cover_glass.refractive_index << YAML::EndMap;
  e << YAML::Key << "optics" << YAML::Value << YAML::BeginMap;
  e << YAML::Key << "mode" << YAML::Value << (c.optics.mode == OpticsMode::kFresnel ? "fresnel" : "far_field");
  e << YAML::Key << "wavelengths_um" << YAML::Value << YAML::Flow << c.optics.wavelengths_um;
  e << YAML::Key << "spectral_weights" << YAML::Value << YAML::Flow << c.optics.spectral_weights;
  e << YAML::Key << "sun_disk" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key << "enabled" << YAML::Value
    << c.optics.sun.enabled << YAML::Key << "angular_diameter_deg" << YAML::Value << c.optics.sun.angular_diameter_deg
    << YAML::Key << "limb_darkening_u" << YAML::Value << c.optics.sun.limb_darkening_u << YAML::EndMap;
  e << YAML::Key << "vignetting" << YAML::Value << c.optics.vignetting;
  e << YAML::Key << "grid_step_um" << YAML::Value << c.optics.grid_step_um;
  e << YAML::Key << "grid_size" << YAML::Value << c.optics.grid_size;
  e << YAML::Key << "psf_node_step_deg" << YAML::Value << c.optics.psf_node_step_deg;
  e << YAML::EndMap;
  e << YAML::Key << "radiometry" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key << "irradiance_w_m2"
    << YAML::Value << c.radiometry.irradiance_w_m2 << YAML::Key << "nd_transmission" << YAML::Value
    << c.radiometry.nd_transmission << YAML::Key << "quantum_efficiency" << YAML::Value
    << c.radiometry.quantum_efficiency << YAML::EndMap;
  e << YAML::Key << "exposure" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key << "mode" << YAML::Value
    << (c.exposure.mode == ExposureMode::kAuto ? "auto" : "fixed") << YAML::Key << "peak_fraction_of_full_well"
    << YAML::Value << c.exposure.peak_fraction_of_full_well << YAML::Key << "exposure_s" << YAML::Value
    << c.exposure.exposure_s << YAML::EndMap;
  const auto& n = c.noise;
  e << YAML::Key << "detector_noise" << YAML::Value << YAML::BeginMap;
  e << YAML::Key << "shot_noise" << YAML::Value << n.shot_noise << YAML::Key << "read_noise_e" << YAML::Value
    << n.read_noise_e << YAML::Key << "full_well_e" << YAML::Value << n.full_well_e << YAML::Key << "adc_full_scale_e"
    << YAML::Value << n.adc_full_scale_e << YAML::Key << "bit_depth" << YAML::Value << n.bit_depth << YAML::Key
    << "black_level_dn" << YAML::Value << n.black_level_dn << YAML::Key << "dark_current_e_per_s" << YAML::Value
    << n.dark_current_e_per_s << YAML::Key << "dark_reference_temp_c" << YAML::Value << n.dark_reference_temp_c
    << YAML::Key << "dark_doubling_temp_c" << YAML::Value << n.dark_doubling_temp_c << YAML::Key << "temperature_c"
    << YAML::Value << n.temperature_c << YAML::Key << "dsnu_fraction" << YAML::Value << n.dsnu_fraction << YAML::Key
    << "prnu_fraction" << YAML::Value << n.prnu_fraction << YAML::EndMap;
  e << YAML::Key << "threshold" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key << "enabled" << YAML::Value
    << c.threshold.enabled << YAML::Key << "level_fraction" << YAML::Value << c.threshold.level_fraction << YAML::Key
    << "rescale" << YAML::Value << c.threshold.rescale << YAML::EndMap;
  const auto& ab = c.as_built;
  e << YAML::Key << "as_built" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key << "height_sigma_um"
    << YAML::Value << ab.height_sigma_um << YAML::Key << "offset_sigma_um" << YAML::Value << ab.offset_sigma_um
    << YAML::Key << "rotation_sigma_deg" << YAML::Value << ab.rotation_sigma_deg << YAML::Key << "tilt_sigma_deg"
    << YAML::Value << ab.tilt_sigma_deg << YAML::Key << "aperture_position_sigma_um" << YAML::Value
    << ab.aperture_position_sigma_um << YAML::Key << "aperture_diameter_sigma_um" << YAML::Value
    << ab.aperture_diameter_sigma_um << YAML::EndMap;
  const auto& an = c.anomalies;
  e << YAML::Key << "anomalies" << YAML::Value << YAML::BeginMap;
  e << YAML::Key << "stray_light" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key << "probability"
    << YAML::Value << an.stray_light_probability << YAML::Key << "max_fraction" << YAML::Value
    << an.stray_light_max_fraction << YAML::EndMap;
  e << YAML::Key << "hot_pixels" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key << "count" << YAML::Value
    << an.hot_pixel_count << YAML::Key << "min_e_per_s" << YAML::Value << an.hot_pixel_min_e_per_s << YAML::Key
    << "max_e_per_s" << YAML::Value << an.hot_pixel_max_e_per_s << YAML::EndMap;
  e << YAML::Key << "debris" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key << "probability" << YAML::Value
    << an.debris_probability << YAML::Key << "max_blocked_fraction" << YAML::Value << an.debris_max_blocked_fraction
    << YAML::EndMap;
  e << YAML::Key << "ghost" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key << "probability" << YAML::Value
    << an.ghost_probability << YAML::Key << "reflectance" << YAML::Value << an.ghost_reflectance << YAML::EndMap;
  e << YAML::EndMap;
  e << YAML::Key << "fov" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key << "alpha_max_deg" << YAML::Value
    << c.fov.alpha_max_deg << YAML::Key << "beta_max_deg" << YAML::Value << c.fov.beta_max_deg << YAML::EndMap;
  e << YAML::Key << "subfov" << YAML::Value << (c.subfov == SubFovType::kQuadrant ? "quadrant" : "nearest_aperture");
  e << YAML::EndMap;
  return e.c_str();
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
