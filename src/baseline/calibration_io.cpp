#include <yaml-cpp/yaml.h>

#include <cmath>
#include <iomanip>
#include <sstream>

#include "digital_sun_sensor/baseline/calibration.h"
#include "digital_sun_sensor/common/file_io.h"
#include "digital_sun_sensor/common/limits.h"
#include "digital_sun_sensor/common/spike_filter.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/common/yaml_reader.h"

namespace dss {
namespace {

constexpr const char* kFormat = "dss_calibration";
constexpr int kVersion = 1;

template <typename T>
T required(const YAML::Node& node, const std::string& key, const std::string& where) {
  if (!node[key]) throw CalibrationError(where + ": missing key '" + key + "'");
  try {
    return node[key].as<T>();
  } catch (const YAML::Exception&) {
    throw CalibrationError(where + ": key '" + key + "' has the wrong type");
  }
}

double finite(double v, const std::string& what) {
  if (!std::isfinite(v)) throw CalibrationError(what + " is not finite");
  return v;
}

}  // namespace

Calibration Calibration::nominalOf(const SensorConfig& config) {
  Calibration c;
  c.sensor = config;
  c.extraction = SpotExtractionConfig::forSensor(config);
  c.geometry = MaskGeometry::nominalOf(config);
  c.polynomial.scale = std::tan(std::max(config.fov.alpha_max_deg, config.fov.beta_max_deg) * kRadPerDeg);
  return c;
}

std::string toYaml(const Calibration& c) {
  YAML::Emitter out;
  out.SetDoublePrecision(17);
  out << YAML::BeginMap;
  out << YAML::Key << "format" << YAML::Value << kFormat << YAML::Key << "version" << YAML::Value << kVersion;
  const auto& e = c.extraction;
  out << YAML::Key << "extraction" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "method" << YAML::Value << toString(e.method);
  out << YAML::Key << "threshold_dn" << YAML::Value << e.threshold_dn;
  out << YAML::Key << "relative_threshold" << YAML::Value << e.relative_threshold;
  out << YAML::Key << "min_area_px" << YAML::Value << e.min_area_px;
  out << YAML::Key << "min_area_fraction" << YAML::Value << e.min_area_fraction;
  out << YAML::Key << "read_noise_dn" << YAML::Value << e.read_noise_dn;
  out << YAML::Key << "electrons_per_dn" << YAML::Value << e.electrons_per_dn;
  out << YAML::Key << "spike_sigmas" << YAML::Value << e.spike_sigmas << YAML::EndMap;
  const auto& g = c.geometry;
  out << YAML::Key << "geometry" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "height_um" << YAML::Value << g.height_um;
  out << YAML::Key << "offset_x_um" << YAML::Value << g.offset_x_um;
  out << YAML::Key << "offset_y_um" << YAML::Value << g.offset_y_um;
  out << YAML::Key << "rotation_deg" << YAML::Value << g.rotation_rad / kRadPerDeg;
  out << YAML::Key << "tilt_x_deg" << YAML::Value << g.tilt_x_rad / kRadPerDeg;
  out << YAML::Key << "tilt_y_deg" << YAML::Value << g.tilt_y_rad / kRadPerDeg;
  out << YAML::Key << "glass_thickness_um" << YAML::Value << g.glass_thickness_um;
  out << YAML::Key << "glass_index" << YAML::Value << g.glass_index;
  out << YAML::Key << "apertures" << YAML::Value << YAML::BeginSeq;
  for (int i = 0; i < g.numApertures(); ++i) {
    out << YAML::Flow << YAML::BeginMap << YAML::Key << "x_um" << YAML::Value << g.apertures_um[i].x() << YAML::Key
        << "y_um" << YAML::Value << g.apertures_um[i].y();
    if (i < static_cast<int>(c.detection_rate.size()))
      out << YAML::Key << "detection_rate" << YAML::Value << c.detection_rate[i];
    out << YAML::EndMap;
  }
  out << YAML::EndSeq << YAML::EndMap;
  const auto& p = c.polynomial;
  out << YAML::Key << "residual_polynomial" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "degree" << YAML::Value << p.degree << YAML::Key << "scale" << YAML::Value << p.scale;
  out << YAML::Key << "alpha_rad" << YAML::Value << YAML::Flow << p.alpha_coefficients;
  out << YAML::Key << "beta_rad" << YAML::Value << YAML::Flow << p.beta_coefficients << YAML::EndMap;
  out << YAML::Key << "centroid_sigma_px" << YAML::Value << c.centroid_sigma_px;
  out << YAML::Key << "fit" << YAML::Value << YAML::Load(c.fit_yaml);
  out << YAML::Key << "sensor" << YAML::Value << YAML::Load(toYaml(c.sensor));
  out << YAML::EndMap;
  return std::string(out.c_str()) + "\n";
}

Calibration parseCalibration(const std::string& yaml_text, const std::string& origin) {
  YAML::Node root;
  try {
    root = loadYaml(yaml_text, origin);
  } catch (const YamlError& ex) {
    throw CalibrationError(ex.what());
  } catch (const YAML::Exception& ex) {
    throw CalibrationError(origin + ": not valid YAML (" + ex.what() + ")");
  }
  if (!root.IsMap() || !root["format"] || root["format"].as<std::string>("") != kFormat)
    throw CalibrationError(origin + ": not a dss calibration file (no 'format: " + kFormat + "')");
  const int version = required<int>(root, "version", origin);
  if (version != kVersion)
    throw CalibrationError(origin + ": calibration format version " + std::to_string(version) +
                           " is not supported (this build reads version " + std::to_string(kVersion) + ")");
  if (!root["sensor"]) throw CalibrationError(origin + ": missing key 'sensor'");
  Calibration c;
  try {
    c.sensor = parseSensorConfig(YAML::Dump(root["sensor"]), origin + " (sensor)");
  } catch (const ConfigError& ex) {
    throw CalibrationError(ex.what());
  }
  c.geometry = MaskGeometry::nominalOf(c.sensor);
  c.extraction = SpotExtractionConfig::forSensor(c.sensor);

  const std::string ew = origin + ": extraction";
  const YAML::Node e = root["extraction"];
  if (!e || !e.IsMap()) throw CalibrationError(ew + " is missing");
  try {
    c.extraction.method = parseCentroidMethod(required<std::string>(e, "method", ew));
  } catch (const std::invalid_argument& ex) {
    throw CalibrationError(ew + ": " + ex.what());
  }
  c.extraction.threshold_dn = finite(required<double>(e, "threshold_dn", ew), ew + ".threshold_dn");
  c.extraction.relative_threshold = finite(required<double>(e, "relative_threshold", ew), ew + ".relative_threshold");
  c.extraction.min_area_px = required<int>(e, "min_area_px", ew);
  c.extraction.min_area_fraction = finite(required<double>(e, "min_area_fraction", ew), ew + ".min_area_fraction");
  c.extraction.read_noise_dn = finite(required<double>(e, "read_noise_dn", ew), ew + ".read_noise_dn");
  c.extraction.electrons_per_dn = finite(required<double>(e, "electrons_per_dn", ew), ew + ".electrons_per_dn");
  // Files written before the hot-pixel repair lack the key: they get the default.
  if (e["spike_sigmas"]) {
    const double sigmas = finite(required<double>(e, "spike_sigmas", ew), ew + ".spike_sigmas");
    if (sigmas < 0.0) throw CalibrationError(ew + ".spike_sigmas must be >= 0 (0: off)");
    c.extraction.spike_sigmas = sigmas;
    c.extraction.spike_margin_dn = spikeMargins(c.sensor, sigmas);
  }

  const std::string gw = origin + ": geometry";
  const YAML::Node g = root["geometry"];
  if (!g || !g.IsMap()) throw CalibrationError(gw + " is missing");
  auto& geo = c.geometry;
  geo.height_um = finite(required<double>(g, "height_um", gw), gw + ".height_um");
  if (geo.height_um <= 0.0) throw CalibrationError(gw + ".height_um must be > 0");
  geo.offset_x_um = finite(required<double>(g, "offset_x_um", gw), gw + ".offset_x_um");
  geo.offset_y_um = finite(required<double>(g, "offset_y_um", gw), gw + ".offset_y_um");
  geo.rotation_rad = finite(required<double>(g, "rotation_deg", gw), gw + ".rotation_deg") * kRadPerDeg;
  geo.tilt_x_rad = finite(required<double>(g, "tilt_x_deg", gw), gw + ".tilt_x_deg") * kRadPerDeg;
  geo.tilt_y_rad = finite(required<double>(g, "tilt_y_deg", gw), gw + ".tilt_y_deg") * kRadPerDeg;
  geo.glass_thickness_um = finite(required<double>(g, "glass_thickness_um", gw), gw + ".glass_thickness_um");
  geo.glass_index = finite(required<double>(g, "glass_index", gw), gw + ".glass_index");
  if (geo.glass_index < 1.0) throw CalibrationError(gw + ".glass_index must be >= 1");
  const YAML::Node apertures = g["apertures"];
  if (!apertures || !apertures.IsSequence() || static_cast<int>(apertures.size()) != geo.numApertures())
    throw CalibrationError(gw + ".apertures must list " + std::to_string(geo.numApertures()) +
                           " apertures (as many as the sensor's mask)");
  for (int i = 0; i < geo.numApertures(); ++i) {
    const std::string aw = gw + ".apertures[" + std::to_string(i) + "]";
    geo.apertures_um[i] = Eigen::Vector2d(finite(required<double>(apertures[i], "x_um", aw), aw + ".x_um"),
                                          finite(required<double>(apertures[i], "y_um", aw), aw + ".y_um"));
    if (apertures[i]["detection_rate"]) {
      const double rate = required<double>(apertures[i], "detection_rate", aw);
      if (!(rate >= 0.0 && rate <= 1.0)) throw CalibrationError(aw + ".detection_rate must be in [0, 1]");
      c.detection_rate.resize(geo.numApertures(), 1.0);
      c.detection_rate[i] = rate;
    }
  }

  const std::string pw = origin + ": residual_polynomial";
  const YAML::Node p = root["residual_polynomial"];
  if (!p || !p.IsMap()) throw CalibrationError(pw + " is missing");
  c.polynomial.degree = required<int>(p, "degree", pw);
  c.polynomial.scale = finite(required<double>(p, "scale", pw), pw + ".scale");
  c.polynomial.alpha_coefficients = required<std::vector<double>>(p, "alpha_rad", pw);
  c.polynomial.beta_coefficients = required<std::vector<double>>(p, "beta_rad", pw);
  if (c.polynomial.degree < 0 || c.polynomial.degree > 8 || !(c.polynomial.scale > 0.0))
    throw CalibrationError(pw + ": degree must be 0..8 and scale > 0");
  const std::size_t terms = c.polynomial.degree > 0 ? ResidualPolynomial::termCount(c.polynomial.degree) : 0;
  if (c.polynomial.alpha_coefficients.size() != terms || c.polynomial.beta_coefficients.size() != terms)
    throw CalibrationError(pw + ": degree " + std::to_string(c.polynomial.degree) + " needs " + std::to_string(terms) +
                           " coefficients per axis");
  for (double v : c.polynomial.alpha_coefficients) finite(v, pw + ".alpha_rad");
  for (double v : c.polynomial.beta_coefficients) finite(v, pw + ".beta_rad");
  c.centroid_sigma_px = finite(required<double>(root, "centroid_sigma_px", origin), origin + ": centroid_sigma_px");
  if (!(c.centroid_sigma_px > 0.0)) throw CalibrationError(origin + ": centroid_sigma_px must be > 0");
  if (root["fit"]) c.fit_yaml = YAML::Dump(root["fit"]);
  // Every other key must be one the format has (the writer emits them all):
  // a misspelt key is refused, not ignored. The sensor section was checked
  // by its own reader.
  YAML::Node given = YAML::Clone(root), known = YAML::Load(toYaml(c));
  given.remove("sensor");
  known.remove("sensor");
  if (const std::string unknown = unknownKeyIn(given, known); !unknown.empty())
    throw CalibrationError(origin + ": " + unknown);
  return c;
}

Calibration loadCalibration(const std::string& path) {
  std::string text;
  try {
    text = readFile(path, limits::kMaxYamlFileBytes);
  } catch (const std::runtime_error& ex) {
    throw CalibrationError(std::string("cannot read calibration: ") + ex.what());
  }
  return parseCalibration(text, path);
}

void saveCalibration(const std::string& path, const Calibration& calibration) {
  writeFileAtomic(path, toYaml(calibration));
}

}  // namespace dss
