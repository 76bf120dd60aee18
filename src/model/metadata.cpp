#include "digital_sun_sensor/model/metadata.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <ctime>
#include <sstream>

#include "digital_sun_sensor/common/limits.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/common/yaml_reader.h"
#include "digital_sun_sensor/model/geometry_design.h"

namespace dss {
namespace {

std::string utcNow() {
  const std::time_t t = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof(buf), "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buf;
}

// A YAML map given as text, checked and re-emitted inline in the metadata.
YAML::Node mapFromText(const std::string& text, const std::string& what) {
  YAML::Node node = YAML::Load(text.empty() ? "{}" : text);
  if (!node.IsMap()) throw ModelError(what + " must be a YAML map");
  return node;
}

template <typename T>
T get(const YAML::Node& parent, const std::string& key, const std::string& origin, const std::string& path) {
  const YAML::Node n = parent[key];
  if (!n) throw ModelError(origin + ": metadata key '" + path + key + "' is missing");
  try {
    return n.as<T>();
  } catch (const YAML::Exception&) {
    throw ModelError(origin + ": metadata key '" + path + key + "' has the wrong type");
  }
}

// Sorted distinct values, merging those within `tolerance`.
std::vector<double> distinctValues(std::vector<double> values, double tolerance) {
  std::sort(values.begin(), values.end());
  std::vector<double> out;
  for (double v : values)
    if (out.empty() || v - out.back() > tolerance) out.push_back(v);
  return out;
}

// Pitch of evenly spaced values centred on 0, or 0 when they are not.
double centredPitch(const std::vector<double>& values, double tolerance) {
  if (values.size() < 2) return 0.0;
  const double pitch = (values.back() - values.front()) / static_cast<double>(values.size() - 1);
  for (std::size_t i = 0; i < values.size(); ++i)
    if (std::abs(values[i] - (values.front() + static_cast<double>(i) * pitch)) > tolerance) return 0.0;
  return std::abs(values.front() + values.back()) > tolerance ? 0.0 : pitch;
}

const char* latticeResolveName(LatticeResolve r) {
  switch (r) {
    case LatticeResolve::kClass:
      return "class";
    case LatticeResolve::kCode:
      return "code";
    default:
      return "centroid";
  }
}

// The lattice head for a full, centred lattice of apertures: whole pitches
// from the coarse centroid when the sub-FOV classes are quadrants; when they
// are the apertures, from the aperture code if the diameters differ (the
// spots then tell the apertures apart), else from the class.
void setLattice(const SensorConfig& config, const HeadOptions& head, ArchSpec& arch) {
  arch.lattice_pitch_x = arch.lattice_pitch_y = 0.0;
  arch.lattice_columns = arch.lattice_rows = 1;
  if (config.mask.apertures.size() < 2) return;
  double min_area_um2 = config.mask.apertures.front().areaUm2(), max_area_um2 = min_area_um2;
  for (const auto& a : config.mask.apertures) {
    min_area_um2 = std::min(min_area_um2, a.areaUm2());
    max_area_um2 = std::max(max_area_um2, a.areaUm2());
  }
  const bool coded = max_area_um2 > 1.2 * min_area_um2;
  arch.lattice_resolve = config.subfov != SubFovType::kNearestAperture ? LatticeResolve::kCentroid
                         : coded                                       ? LatticeResolve::kCode
                                                                       : LatticeResolve::kClass;
  constexpr double kToleranceUm = 0.05;
  std::vector<double> xs, ys;
  for (const auto& a : config.mask.apertures) {
    xs.push_back(a.x_um);
    ys.push_back(a.y_um);
  }
  const auto columns = distinctValues(xs, kToleranceUm), rows = distinctValues(ys, kToleranceUm);
  if (columns.size() * rows.size() != config.mask.apertures.size() || columns.size() < 2 || rows.size() < 2) return;
  const double pitch_x_um = centredPitch(columns, kToleranceUm), pitch_y_um = centredPitch(rows, kToleranceUm);
  if (pitch_x_um <= 0.0 || pitch_y_um <= 0.0) return;
  // Parallel light: spots keep the apertures' spacing on the detector.
  const double pixel_um = config.detector.pitch_um;
  arch.lattice_pitch_x = 2.0 * pitch_x_um / pixel_um / config.detector.width_px;
  arch.lattice_pitch_y = 2.0 * pitch_y_um / pixel_um / config.detector.height_px;
  arch.lattice_columns = static_cast<int>(columns.size());
  arch.lattice_rows = static_cast<int>(rows.size());
  // The phase reads, and the code compares the sizes of, only the spots the
  // edge does not cut: a cut spot's centroid is pulled inward by an amount the
  // head cannot see, more so where stray light widens the lit spot (thesis_ma).
  // For the code, the spot radius is the largest aperture's (as a circle,
  // normalized); thresholded masks keep the default, their lit core's scale.
  arch.lattice_whole_spot_phase = true;
  arch.lattice_spotwise_phase = head.lattice_spotwise_phase;
  arch.lattice_pixel_x = 2.0 / config.detector.width_px;
  arch.lattice_pixel_y = 2.0 / config.detector.height_px;
  if (arch.lattice_resolve == LatticeResolve::kCode)
    arch.lattice_spot_radius = std::sqrt(max_area_um2 / M_PI) / pixel_um /
                               (0.5 * std::min(config.detector.width_px, config.detector.height_px));
}

void clearLattice(ArchSpec& arch) {
  arch.lattice_pitch_x = arch.lattice_pitch_y = 0.0;
  arch.lattice_columns = arch.lattice_rows = 1;
  arch.lattice_whole_spot_phase = arch.lattice_spotwise_phase = false;
  arch.lattice_pixel_x = arch.lattice_pixel_y = 0.0;
}

// Most apertures share their spot with another (fewer groups of overlapping
// spots than half the apertures): thesis_ca's 117 spots, where the
// threshold keeps a network of ridges and no group's light adds up to a
// spot the geometric head could read.
bool spotsMerge(const GeometryDesign& design) {
  return 2 * design.groupCount() < static_cast<int>(design.apertures_um.size());
}

// The geometric or pattern head in place of the mask-family heads (HeadOptions::head).
void setGeometric(const SensorConfig& config, const HeadOptions& head, ArchSpec& arch) {
  validateHeadChoice(head.head);
  const bool family_head = arch.latticeHead() || config.mask.apertures.size() < 2;
  if (head.head == "classic" || (head.head == "auto" && family_head)) return;
  const GeometryDesign design = geometryDesignOf(config);
  // The pattern head reads the image the sites make, which is the whole
  // image only where the chip zeroes what is under its threshold.
  if (head.head == "pattern" && !config.threshold.enabled)
    throw std::invalid_argument("the pattern head needs a sensor that thresholds on chip (sensor '" + config.name +
                                "' has threshold.enabled false)");
  if (head.head == "pattern" || (head.head == "auto" && config.threshold.enabled && spotsMerge(design))) {
    clearLattice(arch);
    arch.pattern_head = true;
    return;
  }
  // An aperture-coded lattice keeps its head as the coarse estimate: the
  // code says which aperture each spot is, which the solve's own search
  // (by the light the spots explain) cannot tell. Other lattices give way
  // to the centroid and the search.
  if (!(arch.latticeHead() && arch.lattice_resolve == LatticeResolve::kCode)) clearLattice(arch);
  arch.geometric_head = true;
  arch.geometric_apertures = static_cast<int>(design.apertures_um.size());
  arch.geometric_groups = design.groupCount();
  arch.geometric_air_above_exit_um = design.air_above_exit_um;
  arch.geometric_gate_um = geometricGateUm(config, design);
  arch.detector_pitch_um = config.detector.pitch_um;
  arch.detector_width_px = config.detector.width_px;
  arch.detector_height_px = config.detector.height_px;
  arch.geometric_class_by_aperture = config.subfov == SubFovType::kNearestAperture;
}

}  // namespace

ModelMetadata metadataFor(const SensorConfig& config, const ArchSpec& arch, const HeadOptions& head) {
  ModelMetadata m;
  m.arch = arch;
  m.arch.num_classes = config.numSubFovClasses();
  if (m.arch.centroid_pool) {
    setLattice(config, head, m.arch);
    // Beyond ~10 deg the tan (and any refraction) bends the position-to-angle
    // map more than a cubic absorbs to the learned terms' resolution.
    constexpr double kWideFieldDeg = 10.0;
    constexpr int kTableSize = 257;
    m.arch.geometric_prior_size =
        std::max(config.fov.alpha_max_deg, config.fov.beta_max_deg) > kWideFieldDeg ? kTableSize : 0;
    setGeometric(config, head, m.arch);
  }
  m.arch.angle_scale_rad = degToRad(std::max(config.fov.alpha_max_deg, config.fov.beta_max_deg));
  m.arch.validate();
  m.input = inputSpecFor(config);
  if (m.arch.pattern_head) m.input.max_sites = m.input.width_px * m.input.height_px;  // every lit pixel
  m.angle_scale_rad = degToRad(std::max(config.fov.alpha_max_deg, config.fov.beta_max_deg));
  m.sensor_name = config.name;
  m.sensor_yaml = toYaml(config);
  m.training_yaml = "{}";
  m.metrics_yaml = "{}";
  m.created_utc = utcNow();
  return m;
}

std::string metadataToYaml(const ModelMetadata& m) {
  YAML::Emitter e;
  e << YAML::BeginMap;
  e << YAML::Key << "format" << YAML::Value << "digital_sun_sensor SSCNN model";
  e << YAML::Key << "created_utc" << YAML::Value << m.created_utc;
  e << YAML::Key << "arch" << YAML::Value << YAML::BeginMap;
  e << YAML::Key << "name" << YAML::Value << m.arch.name;
  e << YAML::Key << "input_channels" << YAML::Value << m.arch.input_channels;
  e << YAML::Key << "stem_width" << YAML::Value << m.arch.stem_width;
  e << YAML::Key << "stem_kernel" << YAML::Value << m.arch.stem_kernel;
  e << YAML::Key << "stem_max_pool" << YAML::Value << m.arch.stem_max_pool;
  e << YAML::Key << "blocks" << YAML::Value << YAML::Flow << m.arch.blocks;
  e << YAML::Key << "widths" << YAML::Value << YAML::Flow << m.arch.widths;
  e << YAML::Key << "batch_norm" << YAML::Value << m.arch.batch_norm;
  e << YAML::Key << "centroid_pool" << YAML::Value << m.arch.centroid_pool;
  e << YAML::Key << "centroid_width" << YAML::Value << m.arch.centroid_width;
  e << YAML::Key << "centroid_weighting" << YAML::Value << centroidWeightingName(m.arch.centroid_weighting);
  e << YAML::Key << "value_saturation" << YAML::Value << m.arch.value_saturation;
  e << YAML::Key << "centroid_degree" << YAML::Value << m.arch.centroid_degree;
  e << YAML::Key << "residual_scale" << YAML::Value << m.arch.residual_scale;
  e << YAML::Key << "feature_corrections" << YAML::Value << m.arch.feature_corrections;
  if (m.arch.latticeHead()) {
    e << YAML::Key << "lattice_pitch_x" << YAML::Value << m.arch.lattice_pitch_x;
    e << YAML::Key << "lattice_pitch_y" << YAML::Value << m.arch.lattice_pitch_y;
    e << YAML::Key << "lattice_columns" << YAML::Value << m.arch.lattice_columns;
    e << YAML::Key << "lattice_rows" << YAML::Value << m.arch.lattice_rows;
    e << YAML::Key << "lattice_spot_radius" << YAML::Value << m.arch.lattice_spot_radius;
    e << YAML::Key << "lattice_resolve" << YAML::Value << latticeResolveName(m.arch.lattice_resolve);
    e << YAML::Key << "lattice_whole_spot_phase" << YAML::Value << m.arch.lattice_whole_spot_phase;
    e << YAML::Key << "lattice_spotwise_phase" << YAML::Value << m.arch.lattice_spotwise_phase;
    if (m.arch.lattice_spotwise_phase) {
      e << YAML::Key << "lattice_pixel_x" << YAML::Value << m.arch.lattice_pixel_x;
      e << YAML::Key << "lattice_pixel_y" << YAML::Value << m.arch.lattice_pixel_y;
    }
  }
  if (m.arch.geometric_prior_size > 0)
    e << YAML::Key << "geometric_prior_size" << YAML::Value << m.arch.geometric_prior_size;
  if (m.arch.geometric_head) {
    e << YAML::Key << "geometric_head" << YAML::Value << true;
    e << YAML::Key << "geometric_apertures" << YAML::Value << m.arch.geometric_apertures;
    e << YAML::Key << "geometric_groups" << YAML::Value << m.arch.geometric_groups;
    e << YAML::Key << "geometric_air_above_exit_um" << YAML::Value << m.arch.geometric_air_above_exit_um;
    e << YAML::Key << "geometric_gate_um" << YAML::Value << m.arch.geometric_gate_um;
    if (m.arch.geometric_symmetric_spots) e << YAML::Key << "geometric_symmetric_spots" << YAML::Value << true;
    e << YAML::Key << "detector_pitch_um" << YAML::Value << m.arch.detector_pitch_um;
    e << YAML::Key << "detector_width_px" << YAML::Value << m.arch.detector_width_px;
    e << YAML::Key << "detector_height_px" << YAML::Value << m.arch.detector_height_px;
  }
  if (m.arch.pattern_head) e << YAML::Key << "pattern_head" << YAML::Value << true;
  e << YAML::Key << "head_hidden" << YAML::Value << YAML::Flow << m.arch.head_hidden;
  e << YAML::Key << "num_classes" << YAML::Value << m.arch.num_classes;
  e << YAML::EndMap;
  e << YAML::Key << "input" << YAML::Value << YAML::BeginMap;
  e << YAML::Key << "features" << YAML::Value << YAML::Flow << std::vector<std::string>{"value", "x", "y"};
  e << YAML::Key << "width_px" << YAML::Value << m.input.width_px;
  e << YAML::Key << "height_px" << YAML::Value << m.input.height_px;
  e << YAML::Key << "max_code" << YAML::Value << m.input.max_code;
  e << YAML::Key << "black_level_dn" << YAML::Value << m.input.black_level_dn;
  e << YAML::Key << "threshold_dn" << YAML::Value << m.input.threshold_dn;
  e << YAML::Key << "max_sites" << YAML::Value << m.input.max_sites;
  e << YAML::EndMap;
  e << YAML::Key << "angle_scale_rad" << YAML::Value << m.angle_scale_rad;
  if (m.angle_correction.active()) {
    e << YAML::Key << "angle_correction" << YAML::Value << YAML::BeginMap;
    e << YAML::Key << "degree" << YAML::Value << m.angle_correction.degree;
    e << YAML::Key << "alpha" << YAML::Value << YAML::Flow << m.angle_correction.alpha;
    e << YAML::Key << "beta" << YAML::Value << YAML::Flow << m.angle_correction.beta;
    e << YAML::EndMap;
  }
  if (!m.height_corrections.empty()) {
    e << YAML::Key << "angle_correction_height" << YAML::Value << YAML::BeginSeq;
    for (const HeightCorrection& h : m.height_corrections) {
      e << YAML::BeginMap;
      e << YAML::Key << "height_change_um" << YAML::Value << h.height_change_um;
      e << YAML::Key << "degree" << YAML::Value << h.change.degree;
      e << YAML::Key << "alpha" << YAML::Value << YAML::Flow << h.change.alpha;
      e << YAML::Key << "beta" << YAML::Value << YAML::Flow << h.change.beta;
      e << YAML::EndMap;
    }
    e << YAML::EndSeq;
  }
  e << YAML::Key << "inference_symmetry" << YAML::Value << inferenceSymmetryName(m.inference_symmetry);
  if (m.sigma_site_law.active()) {
    e << YAML::Key << "sigma_site_law" << YAML::Value << YAML::BeginMap;
    e << YAML::Key << "exponent" << YAML::Value << m.sigma_site_law.exponent;
    e << YAML::Key << "reference_sites" << YAML::Value << m.sigma_site_law.reference_sites;
    e << YAML::EndMap;
  }
  if (m.mismatch_level > 0.0) {
    e << YAML::Key << "spot_mismatch" << YAML::Value << YAML::BeginMap;
    e << YAML::Key << "level" << YAML::Value << m.mismatch_level;
    e << YAML::Key << "threshold" << YAML::Value << m.mismatch_threshold;
    e << YAML::EndMap;
  }
  if (m.arch.geometric_head)
    e << YAML::Key << "geometry_sigma_rad" << YAML::Value << YAML::Flow << YAML::BeginSeq << m.geometry_sigma_rad[0]
      << m.geometry_sigma_rad[1] << YAML::EndSeq;
  if (!m.aperture_variance_um2.empty()) {
    e << YAML::Key << "aperture_position" << YAML::Value << YAML::BeginMap;
    e << YAML::Key << "variance_um2" << YAML::Value << YAML::Flow << m.aperture_variance_um2;
    e << YAML::Key << "spot_noise_um2" << YAML::Value << m.spot_noise_um2;
    e << YAML::EndMap;
  }
  if (m.spot_bias.active()) {
    e << YAML::Key << "spot_bias" << YAML::Value << YAML::BeginMap;
    e << YAML::Key << "degree" << YAML::Value << m.spot_bias.degree;
    e << YAML::Key << "angle_scale_rad" << YAML::Value << m.spot_bias.angle_scale_rad;
    e << YAML::Key << "group_class" << YAML::Value << YAML::Flow << m.spot_bias.group_class;
    auto coefficients = [&e](const std::vector<std::vector<double>>& x_um,
                             const std::vector<std::vector<double>>& y_um) {
      for (const auto& [key, axis] : {std::pair{"x_um", &x_um}, std::pair{"y_um", &y_um}}) {
        e << YAML::Key << key << YAML::Value << YAML::BeginSeq;
        for (const auto& c : *axis) e << YAML::Flow << c;
        e << YAML::EndSeq;
      }
    };
    coefficients(m.spot_bias.x_um, m.spot_bias.y_um);
    if (!m.spot_bias.by_height.empty()) {
      e << YAML::Key << "by_height" << YAML::Value << YAML::BeginSeq;
      for (const SpotBiasChange& c : m.spot_bias.by_height) {
        e << YAML::BeginMap;
        e << YAML::Key << "height_change_um" << YAML::Value << c.height_change_um;
        e << YAML::Key << "degree" << YAML::Value << c.degree;
        coefficients(c.x_um, c.y_um);
        e << YAML::EndMap;
      }
      e << YAML::EndSeq;
    }
    e << YAML::EndMap;
  }
  e << YAML::Key << "sensor_name" << YAML::Value << m.sensor_name;
  if (m.unit_yaml != "{}") e << YAML::Key << "unit" << YAML::Value << mapFromText(m.unit_yaml, "unit calibration");
  e << YAML::Key << "training" << YAML::Value << mapFromText(m.training_yaml, "training summary");
  e << YAML::Key << "metrics" << YAML::Value << mapFromText(m.metrics_yaml, "metrics");
  e << YAML::Key << "sensor" << YAML::Value << YAML::Literal << m.sensor_yaml;
  e << YAML::EndMap;
  return e.c_str();
}

ModelMetadata metadataFromYaml(const std::string& text, const std::string& origin) {
  YAML::Node root;
  try {
    root = loadYaml(text, origin);
  } catch (const YamlError& e) {
    throw ModelError(e.what());
  } catch (const YAML::Exception& e) {
    throw ModelError(origin + ": metadata is not valid YAML: " + e.what());
  }
  if (!root.IsMap()) throw ModelError(origin + ": metadata is not a YAML map");
  ModelMetadata m;
  m.created_utc = get<std::string>(root, "created_utc", origin, "");
  const YAML::Node a = root["arch"];
  if (!a || !a.IsMap()) throw ModelError(origin + ": metadata key 'arch' is missing");
  m.arch.name = get<std::string>(a, "name", origin, "arch.");
  m.arch.input_channels = get<int>(a, "input_channels", origin, "arch.");
  m.arch.stem_width = get<int>(a, "stem_width", origin, "arch.");
  m.arch.stem_kernel = get<int>(a, "stem_kernel", origin, "arch.");
  m.arch.stem_max_pool = get<bool>(a, "stem_max_pool", origin, "arch.");
  m.arch.blocks = get<std::vector<int>>(a, "blocks", origin, "arch.");
  m.arch.widths = get<std::vector<int>>(a, "widths", origin, "arch.");
  m.arch.batch_norm = get<bool>(a, "batch_norm", origin, "arch.");
  m.arch.centroid_pool = get<bool>(a, "centroid_pool", origin, "arch.");
  m.arch.centroid_width = get<int>(a, "centroid_width", origin, "arch.");
  if (a["centroid_weighting"]) {  // absent in models made before it existed: learned
    try {
      m.arch.centroid_weighting = parseCentroidWeighting(get<std::string>(a, "centroid_weighting", origin, "arch."));
    } catch (const std::invalid_argument& e) {
      throw ModelError(origin + ": metadata key 'arch.centroid_weighting': " + e.what());
    }
  }
  if (a["value_saturation"]) {  // absent in models made before it existed: 0
    m.arch.value_saturation = get<double>(a, "value_saturation", origin, "arch.");
    if (!(m.arch.value_saturation >= 0.0) || !std::isfinite(m.arch.value_saturation))
      throw ModelError(origin + ": metadata key 'arch.value_saturation' must be finite and >= 0");
  }
  m.arch.centroid_degree = get<int>(a, "centroid_degree", origin, "arch.");
  m.arch.residual_scale = get<double>(a, "residual_scale", origin, "arch.");
  if (a["feature_corrections"])  // absent in models made before it existed: on
    m.arch.feature_corrections = get<bool>(a, "feature_corrections", origin, "arch.");
  if (a["lattice_pitch_x"]) {  // absent in models without the lattice head
    m.arch.lattice_pitch_x = get<double>(a, "lattice_pitch_x", origin, "arch.");
    m.arch.lattice_pitch_y = get<double>(a, "lattice_pitch_y", origin, "arch.");
    m.arch.lattice_columns = get<int>(a, "lattice_columns", origin, "arch.");
    m.arch.lattice_rows = get<int>(a, "lattice_rows", origin, "arch.");
    m.arch.lattice_spot_radius = get<double>(a, "lattice_spot_radius", origin, "arch.");
    const std::string resolve =
        a["lattice_resolve"] ? get<std::string>(a, "lattice_resolve", origin, "arch.") : "centroid";
    if (a["lattice_whole_spot_phase"])  // absent in models made before it existed: off
      m.arch.lattice_whole_spot_phase = get<bool>(a, "lattice_whole_spot_phase", origin, "arch.");
    if (a["lattice_spotwise_phase"])  // absent in models made before it existed: off
      m.arch.lattice_spotwise_phase = get<bool>(a, "lattice_spotwise_phase", origin, "arch.");
    if (m.arch.lattice_spotwise_phase) {
      m.arch.lattice_pixel_x = get<double>(a, "lattice_pixel_x", origin, "arch.");
      m.arch.lattice_pixel_y = get<double>(a, "lattice_pixel_y", origin, "arch.");
    }
    bool known = false;
    for (const auto r : {LatticeResolve::kCentroid, LatticeResolve::kClass, LatticeResolve::kCode})
      if (resolve == latticeResolveName(r)) {
        m.arch.lattice_resolve = r;
        known = true;
      }
    if (!known)
      throw ModelError(origin + ": metadata key 'arch.lattice_resolve' must be 'centroid', 'class' or 'code', not '" +
                       resolve + "'");
  }
  if (a["geometric_prior_size"])  // absent: the linear prior
    m.arch.geometric_prior_size = get<int>(a, "geometric_prior_size", origin, "arch.");
  if (a["geometric_head"]) {  // absent: the mask-family heads
    m.arch.geometric_head = get<bool>(a, "geometric_head", origin, "arch.");
    m.arch.geometric_apertures = get<int>(a, "geometric_apertures", origin, "arch.");
    m.arch.geometric_groups = get<int>(a, "geometric_groups", origin, "arch.");
    if (a["geometric_air_above_exit_um"])
      m.arch.geometric_air_above_exit_um = get<double>(a, "geometric_air_above_exit_um", origin, "arch.");
    m.arch.geometric_gate_um = get<double>(a, "geometric_gate_um", origin, "arch.");
    if (a["geometric_symmetric_spots"])  // absent: weighted centroids
      m.arch.geometric_symmetric_spots = get<bool>(a, "geometric_symmetric_spots", origin, "arch.");
    m.arch.detector_pitch_um = get<double>(a, "detector_pitch_um", origin, "arch.");
    m.arch.detector_width_px = get<int>(a, "detector_width_px", origin, "arch.");
    m.arch.detector_height_px = get<int>(a, "detector_height_px", origin, "arch.");
  }
  if (a["pattern_head"])  // absent: another head
    m.arch.pattern_head = get<bool>(a, "pattern_head", origin, "arch.");
  m.arch.head_hidden = get<std::vector<int>>(a, "head_hidden", origin, "arch.");
  m.arch.num_classes = get<int>(a, "num_classes", origin, "arch.");
  m.arch.angle_scale_rad = get<double>(root, "angle_scale_rad", origin, "");
  try {
    m.arch.validate();
  } catch (const std::invalid_argument& e) {
    throw ModelError(origin + ": " + e.what());
  }
  const YAML::Node in = root["input"];
  if (!in || !in.IsMap()) throw ModelError(origin + ": metadata key 'input' is missing");
  m.input.width_px = get<int>(in, "width_px", origin, "input.");
  m.input.height_px = get<int>(in, "height_px", origin, "input.");
  m.input.max_code = get<int>(in, "max_code", origin, "input.");
  m.input.black_level_dn = get<double>(in, "black_level_dn", origin, "input.");
  m.input.threshold_dn = get<double>(in, "threshold_dn", origin, "input.");
  m.input.max_sites = get<int>(in, "max_sites", origin, "input.");
  if (m.input.width_px < 1 || m.input.height_px < 1 || m.input.max_code < 1 || m.input.max_sites < 1)
    throw ModelError(origin + ": metadata 'input' has a non-positive size");
  if (m.input.width_px > limits::kMaxDetectorSidePx || m.input.height_px > limits::kMaxDetectorSidePx ||
      static_cast<std::size_t>(m.input.max_sites) > limits::kMaxSitesPerImage)
    throw ModelError(origin + ": metadata 'input' is over the limits (" + std::to_string(limits::kMaxDetectorSidePx) +
                     " px a side, " + std::to_string(limits::kMaxSitesPerImage) + " sites)");
  m.angle_scale_rad = get<double>(root, "angle_scale_rad", origin, "");
  if (!(m.angle_scale_rad > 0.0)) throw ModelError(origin + ": metadata 'angle_scale_rad' must be positive");
  if (const YAML::Node c = root["angle_correction"]) {  // absent: none
    if (!c.IsMap()) throw ModelError(origin + ": metadata key 'angle_correction' is not a map");
    m.angle_correction.degree = get<int>(c, "degree", origin, "angle_correction.");
    m.angle_correction.alpha = get<std::vector<double>>(c, "alpha", origin, "angle_correction.");
    m.angle_correction.beta = get<std::vector<double>>(c, "beta", origin, "angle_correction.");
    try {
      m.angle_correction.validate();
    } catch (const std::invalid_argument& e) {
      throw ModelError(origin + ": metadata key 'angle_correction': " + e.what());
    }
  }
  if (const YAML::Node list = root["angle_correction_height"]) {  // absent: the correction stays with the height
    const std::string key = "angle_correction_height";
    if (!list.IsSequence()) throw ModelError(origin + ": metadata key '" + key + "' is not a list");
    for (std::size_t i = 0; i < list.size(); ++i) {
      const std::string at = key + "[" + std::to_string(i) + "].";
      if (!list[i].IsMap()) throw ModelError(origin + ": metadata key '" + at + "' is not a map");
      HeightCorrection h;
      h.height_change_um = get<double>(list[i], "height_change_um", origin, at);
      h.change.degree = get<int>(list[i], "degree", origin, at);
      h.change.alpha = get<std::vector<double>>(list[i], "alpha", origin, at);
      h.change.beta = get<std::vector<double>>(list[i], "beta", origin, at);
      try {
        h.validate();
      } catch (const std::invalid_argument& e) {
        throw ModelError(origin + ": metadata key '" + at + "': " + e.what());
      }
      for (const HeightCorrection& other : m.height_corrections)
        if (other.height_change_um == h.height_change_um)
          throw ModelError(origin + ": metadata key '" + key + "' holds two entries for " +
                           std::to_string(h.height_change_um) + " um");
      m.height_corrections.push_back(h);
    }
  }
  if (const YAML::Node law = root["sigma_site_law"]) {  // absent: sigma does not follow the lit sites
    if (!law.IsMap()) throw ModelError(origin + ": metadata key 'sigma_site_law' is not a map");
    m.sigma_site_law.exponent = get<double>(law, "exponent", origin, "sigma_site_law.");
    m.sigma_site_law.reference_sites = get<double>(law, "reference_sites", origin, "sigma_site_law.");
    if (!std::isfinite(m.sigma_site_law.exponent) || std::abs(m.sigma_site_law.exponent) > 10.0 ||
        !(m.sigma_site_law.reference_sites > 0.0) || !std::isfinite(m.sigma_site_law.reference_sites))
      throw ModelError(origin + ": metadata key 'sigma_site_law' needs an exponent within +-10 and a positive " +
                       "reference_sites");
  }
  if (const YAML::Node mismatch = root["spot_mismatch"]) {  // absent: not measured
    if (!mismatch.IsMap()) throw ModelError(origin + ": metadata key 'spot_mismatch' is not a map");
    m.mismatch_level = get<double>(mismatch, "level", origin, "spot_mismatch.");
    m.mismatch_threshold = get<double>(mismatch, "threshold", origin, "spot_mismatch.");
    if (!(m.mismatch_level > 0.0) || !std::isfinite(m.mismatch_level) || !(m.mismatch_threshold > 0.0) ||
        !std::isfinite(m.mismatch_threshold) || !m.arch.geometric_head)
      throw ModelError(origin +
                       ": metadata key 'spot_mismatch' needs a positive level and threshold, and a "
                       "geometric head");
  }
  if (const YAML::Node sigma = root["geometry_sigma_rad"]) {  // absent: the design's geometry
    const auto bad = [&] {
      return ModelError(origin +
                        ": metadata key 'geometry_sigma_rad' must be two finite non-negative numbers (alpha, beta), "
                        "in a model with a geometric head");
    };
    if (!sigma.IsSequence() || sigma.size() != 2 || !m.arch.geometric_head) throw bad();
    for (std::size_t k = 0; k < 2; ++k) {
      try {
        m.geometry_sigma_rad[k] = sigma[k].as<double>();
      } catch (const YAML::Exception&) {
        throw bad();
      }
      if (!(m.geometry_sigma_rad[k] >= 0.0) || !std::isfinite(m.geometry_sigma_rad[k])) throw bad();
    }
  }
  if (const YAML::Node position = root["aperture_position"]) {  // absent: positions exact (the design)
    const std::string at = "aperture_position.";
    if (!position.IsMap() || !m.arch.geometric_head)
      throw ModelError(origin + ": metadata key 'aperture_position' must be a map, in a model with a geometric head");
    m.aperture_variance_um2 = get<std::vector<double>>(position, "variance_um2", origin, at);
    m.spot_noise_um2 = get<double>(position, "spot_noise_um2", origin, at);
    bool finite = !m.aperture_variance_um2.empty();
    for (double v : m.aperture_variance_um2) finite = finite && v >= 0.0 && std::isfinite(v);
    if (!finite || !(m.spot_noise_um2 > 0.0) || !std::isfinite(m.spot_noise_um2))
      throw ModelError(origin + ": metadata key 'aperture_position' needs finite non-negative variances and a " +
                       "positive spot_noise_um2");
  }
  if (const YAML::Node bias = root["spot_bias"]) {  // absent: none
    const std::string at = "spot_bias.";
    if (!bias.IsMap() || !m.arch.geometric_head)
      throw ModelError(origin + ": metadata key 'spot_bias' must be a map, in a model with a geometric head");
    m.spot_bias.degree = get<int>(bias, "degree", origin, at);
    m.spot_bias.angle_scale_rad = get<double>(bias, "angle_scale_rad", origin, at);
    m.spot_bias.group_class = get<std::vector<int>>(bias, "group_class", origin, at);
    m.spot_bias.x_um = get<std::vector<std::vector<double>>>(bias, "x_um", origin, at);
    m.spot_bias.y_um = get<std::vector<std::vector<double>>>(bias, "y_um", origin, at);
    if (const YAML::Node list = bias["by_height"]) {  // absent: the bias stays with the height
      if (!list.IsSequence()) throw ModelError(origin + ": metadata key 'spot_bias.by_height' is not a list");
      for (std::size_t i = 0; i < list.size(); ++i) {
        const std::string entry = at + "by_height[" + std::to_string(i) + "].";
        if (!list[i].IsMap()) throw ModelError(origin + ": metadata key '" + entry + "' is not a map");
        SpotBiasChange c;
        c.height_change_um = get<double>(list[i], "height_change_um", origin, entry);
        c.degree = get<int>(list[i], "degree", origin, entry);
        c.x_um = get<std::vector<std::vector<double>>>(list[i], "x_um", origin, entry);
        c.y_um = get<std::vector<std::vector<double>>>(list[i], "y_um", origin, entry);
        m.spot_bias.by_height.push_back(std::move(c));
      }
    }
    if (!m.spot_bias.active()) throw ModelError(origin + ": metadata key 'spot_bias.degree' must be 0 or more");
  }
  m.sensor_name = get<std::string>(root, "sensor_name", origin, "");
  if (const YAML::Node unit = root["unit"]) {  // absent: the nominal design
    if (!unit.IsMap() || !m.arch.geometric_head)
      throw ModelError(origin + ": metadata key 'unit' must be a map, in a model with a geometric head");
    m.unit_yaml = YAML::Dump(unit);
  }
  m.sensor_yaml = get<std::string>(root, "sensor", origin, "");
  if (m.arch.geometric_head) {  // the class scheme comes with the sensor
    try {
      m.arch.geometric_class_by_aperture =
          parseSensorConfig(m.sensor_yaml, origin + " (embedded sensor config)").subfov == SubFovType::kNearestAperture;
    } catch (const ConfigError& e) {
      throw ModelError(e.what());
    }
  }
  if (root["inference_symmetry"]) {  // absent in models made before it existed: none
    try {
      m.inference_symmetry = parseInferenceSymmetry(get<std::string>(root, "inference_symmetry", origin, ""));
    } catch (const std::invalid_argument& e) {
      throw ModelError(origin + ": metadata key 'inference_symmetry': " + e.what());
    }
    if (m.inference_symmetry != InferenceSymmetry::kNone && (m.arch.geometric_head || m.arch.pattern_head))
      throw ModelError(origin + ": metadata key 'inference_symmetry' is '" +
                       inferenceSymmetryName(m.inference_symmetry) + "' but the " + headName(m.arch) +
                       " head solves through the sensor's own geometry (none only)");
    if (m.inference_symmetry != InferenceSymmetry::kNone) {
      std::string why;
      try {
        why = symmetryMismatch(parseSensorConfig(m.sensor_yaml, origin + " (embedded sensor config)"),
                               m.inference_symmetry);
      } catch (const ConfigError& e) {
        throw ModelError(e.what());
      }
      if (!why.empty())
        throw ModelError(origin + ": metadata key 'inference_symmetry' is '" +
                         inferenceSymmetryName(m.inference_symmetry) + "' but the sensor lacks that symmetry: " + why);
    }
  }
  m.training_yaml = YAML::Dump(root["training"] ? root["training"] : YAML::Node(YAML::NodeType::Map));
  m.metrics_yaml = YAML::Dump(root["metrics"] ? root["metrics"] : YAML::Node(YAML::NodeType::Map));
  // Every key must be one the format has (the writer emits each for the value
  // read): a misspelt key is refused, not ignored.
  if (const std::string unknown = unknownKeyIn(root, YAML::Load(metadataToYaml(m))); !unknown.empty())
    throw ModelError(origin + ": metadata: " + unknown);
  return m;
}

void checkSensorCompatible(const ModelMetadata& meta, const SensorConfig& config, const std::string& origin) {
  SensorConfig trained;
  try {
    trained = parseSensorConfig(meta.sensor_yaml, origin + " (embedded sensor config)");
  } catch (const ConfigError& e) {
    throw ModelError(e.what());
  }
  const std::string mismatch = sensorDesignMismatch(trained, config);
  if (!mismatch.empty()) throw ModelError(origin + ": the model was made for " + mismatch);
  if (meta.arch.num_classes != config.numSubFovClasses())
    throw ModelError(origin + ": the model has " + std::to_string(meta.arch.num_classes) +
                     " sub-FOV classes, sensor '" + config.name + "' " + std::to_string(config.numSubFovClasses()));
}

}  // namespace dss
