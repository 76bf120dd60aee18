// Sensor configuration: everything the simulator (and later the estimators)
// needs to know about one digital sun sensor design. Loaded from YAML
// (config/sensors/*.yaml); docs/simulator.md describes the model behind each key.
#pragma once

#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

#include "digital_sun_sensor/common/units.h"

namespace dss {

// A configuration problem. The message names the file and the key path.
class ConfigError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

enum class ApertureShape { kCircle, kRectangle };

// An opaque disk covering part of an aperture (debris, contamination).
struct Occluder {
  double x_um = 0.0;  // centre, relative to the aperture centre
  double y_um = 0.0;
  double radius_um = 0.0;
};

struct ApertureConfig {
  double x_um = 0.0;  // centre in the mask frame (mask centre = boresight)
  double y_um = 0.0;
  ApertureShape shape = ApertureShape::kCircle;
  double diameter_um = 0.0;  // circle
  double width_um = 0.0;     // rectangle (along x before rotation)
  double height_um = 0.0;    // rectangle (along y before rotation)
  double rotation_deg = 0.0;
  std::vector<Occluder> occluders;  // filled by debris draws, never from YAML

  // Open area without occluders.
  double areaUm2() const {
    return shape == ApertureShape::kCircle ? 0.25 * kPi * diameter_um * diameter_um : width_um * height_um;
  }
  // The diameter of a circle of the same open area.
  double equivalentDiameterUm() const { return 2.0 * std::sqrt(areaUm2() / kPi); }
};

struct DetectorConfig {
  int width_px = 512;
  int height_px = 512;
  double pitch_um = 1.55;
};

struct MaskConfig {
  double height_mm = 5.0;     // detector surface to the mask's lower (exit) face
  double thickness_mm = 0.0;  // vignetting at oblique incidence
  std::vector<ApertureConfig> apertures;
};

struct CoverGlassConfig {
  bool enabled = false;
  double thickness_mm = 0.0;  // glass lies on the detector, below the mask
  double refractive_index = 1.5;
};

enum class OpticsMode { kFresnel, kFarField };

struct SunDiskConfig {
  bool enabled = true;
  double angular_diameter_deg = 0.533;
  double limb_darkening_u = 0.56;  // linear law I(mu) = 1 - u (1 - mu)
};

struct OpticsConfig {
  OpticsMode mode = OpticsMode::kFresnel;
  std::vector<double> wavelengths_um;
  std::vector<double> spectral_weights;  // AM0 x sensor response, any scale
  SunDiskConfig sun;
  bool vignetting = true;          // mask-thickness clipping at oblique incidence
  double grid_step_um = 1.0;       // diffraction sampling on mask and detector
  int grid_size = 512;             // FFT size (grid_size * grid_step_um = window)
  double psf_node_step_deg = 1.0;  // spot shapes cached on this incidence grid
};

struct RadiometryConfig {
  double irradiance_w_m2 = 1361.0;  // AM0 solar constant
  double nd_transmission = 1e-3;    // neutral-density filter
  double quantum_efficiency = 0.5;  // at the spectrum's weighted mean wavelength
};

enum class ExposureMode { kAuto, kFixed };

struct ExposureConfig {
  ExposureMode mode = ExposureMode::kAuto;
  double peak_fraction_of_full_well = 1.0;  // auto: brightest spot pixel
  double exposure_s = 1e-3;                 // fixed
};

// EMVA 1288 detector terms.
struct DetectorNoiseConfig {
  bool shot_noise = true;
  double read_noise_e = 3.0;
  double full_well_e = 8180.0;
  double adc_full_scale_e = 8180.0;  // electrons mapped to the top code
  int bit_depth = 8;
  double black_level_dn = 0.0;
  double dark_current_e_per_s = 0.0;  // at dark_reference_temp_c
  double dark_reference_temp_c = 25.0;
  double dark_doubling_temp_c = 6.5;
  double temperature_c = 25.0;
  double dsnu_fraction = 0.0;  // per-pixel dark current spread (std / mean)
  double prnu_fraction = 0.0;  // per-pixel gain spread (std / mean)

  // Mean dark current at temperature_c: doubles every dark_doubling_temp_c.
  double darkCurrentAtTemperatureEPerS() const;
};

struct ThresholdConfig {
  bool enabled = false;
  double level_fraction = 0.9;  // of the top code
  bool rescale = true;          // map [level, top] onto [0, top]
};

// Per-sensor manufacturing errors: standard deviations of Gaussian draws.
struct AsBuiltConfig {
  double height_sigma_um = 0.0;
  double offset_sigma_um = 0.0;
  double rotation_sigma_deg = 0.0;
  double tilt_sigma_deg = 0.0;
  double aperture_position_sigma_um = 0.0;
  double aperture_diameter_sigma_um = 0.0;
};

// Typical manufacturing tolerances times `scale` (`as_built=S` of `dss
// generate --anomalies`): 1 sigma of 20 um mask height, 10 um offset, 0.2 deg
// rotation, 0.1 deg tilt, 1 um aperture position and 1 um diameter.
AsBuiltConfig asBuiltTolerances(double scale);

struct AnomalyConfig {
  // Stray light / Earth albedo: smooth gradient, per image with a probability.
  double stray_light_probability = 0.0;
  double stray_light_max_fraction = 0.2;  // of full well at the bright edge
  // Hot pixels: fixed per sensor, dark current log-uniform in [min, max].
  int hot_pixel_count = 0;
  double hot_pixel_min_e_per_s = 1e5;
  double hot_pixel_max_e_per_s = 1e7;
  // Debris partly covering apertures: per sensor and aperture.
  double debris_probability = 0.0;
  double debris_max_blocked_fraction = 0.3;
  // Ghost: detector -> mask underside -> detector reflection, per image.
  double ghost_probability = 0.0;
  double ghost_reflectance = 0.02;
};

struct FieldOfViewConfig {
  double alpha_max_deg = 4.54;
  double beta_max_deg = 4.54;
};

enum class SubFovType { kQuadrant, kNearestAperture };

struct SensorConfig {
  std::string name;
  std::string source_path;  // file it was loaded from, for messages
  DetectorConfig detector;
  MaskConfig mask;
  CoverGlassConfig cover_glass;
  OpticsConfig optics;
  RadiometryConfig radiometry;
  ExposureConfig exposure;
  DetectorNoiseConfig noise;
  ThresholdConfig threshold;
  AsBuiltConfig as_built;
  AnomalyConfig anomalies;
  FieldOfViewConfig fov;
  SubFovType subfov = SubFovType::kQuadrant;

  int maxCode() const { return (1 << noise.bit_depth) - 1; }
  int numSubFovClasses() const;
};

// Loads and validates a sensor config. `overrides` are "dotted.key=value"
// strings applied to the YAML before validation (e.g. "optics.mode=far_field").
// Throws ConfigError naming the file and key on any problem.
SensorConfig loadSensorConfig(const std::string& path, const std::vector<std::string>& overrides = {});

// Same, from YAML text (`origin` names it in messages).
SensorConfig parseSensorConfig(const std::string& yaml_text, const std::string& origin,
                               const std::vector<std::string>& overrides = {});

// Empty when a model or calibration made for `made_for` fits images of
// `config` (same detector, readout and mask layout, within as-built
// tolerances); else "sensor 'A' with KEY = a, but sensor 'B' has b".
std::string sensorDesignMismatch(const SensorConfig& made_for, const SensorConfig& config);

// Canonical YAML of a config, for provenance (model metadata, bag headers).
std::string toYaml(const SensorConfig& config);

}  // namespace dss
