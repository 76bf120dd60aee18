// The sensor config's keys, once: sensorConfigFields() names every key of
// config/sensors/*.yaml with its member, its rule and whether it is required;
// parseSensorConfig() reads a document through it (YamlFieldReader) and
// toYaml() writes one (YamlFieldWriter). An optional key that is absent keeps
// the struct's default (sensor_config.h). Private to sensor_config.cpp.
#pragma once

#include <cstdint>
#include <string>

#include "digital_sun_sensor/common/limits.h"
#include "digital_sun_sensor/common/yaml_fields.h"
#include "digital_sun_sensor/sim/sensor_config.h"

namespace dss {

template <typename Fields>
void apertureFields(Fields& f, ApertureConfig& a) {
  enum class Shape { kCircle, kSquare, kRectangle };  // a square is read as a rectangle
  Shape shape = a.shape == ApertureShape::kCircle ? Shape::kCircle : Shape::kRectangle;
  f.number("x_um", a.x_um, Bound::kAny);
  f.number("y_um", a.y_um, Bound::kAny);
  f.choice("shape", shape, {{"circle", Shape::kCircle}, {"square", Shape::kSquare}, {"rectangle", Shape::kRectangle}},
           "aperture shape");
  a.shape = shape == Shape::kCircle ? ApertureShape::kCircle : ApertureShape::kRectangle;
  if (shape == Shape::kCircle) {
    f.number("diameter_um", a.diameter_um, Bound::kPositive, kRequired);
    return;
  }
  if (shape == Shape::kSquare) {
    f.number("side_um", a.width_um, Bound::kPositive, kRequired);
    a.height_um = a.width_um;
  } else {
    f.number("width_um", a.width_um, Bound::kPositive, kRequired);
    f.number("height_um", a.height_um, Bound::kPositive, kRequired);
  }
  f.number("rotation_deg", a.rotation_deg, Bound::kAny);
}

template <typename Fields>
void opticsFields(Fields& f, OpticsConfig& o) {
  f.choice("mode", o.mode, {{"fresnel", OpticsMode::kFresnel}, {"far_field", OpticsMode::kFarField}}, "optics mode");
  f.numbers("wavelengths_um", o.wavelengths_um);
  f.check("wavelengths_um", o.wavelengths_um.size() <= static_cast<std::size_t>(limits::kMaxWavelengths),
          std::to_string(o.wavelengths_um.size()) + " wavelengths, over the limit of " +
              std::to_string(limits::kMaxWavelengths));
  f.numbers("spectral_weights", o.spectral_weights);
  f.check("spectral_weights", o.spectral_weights.size() == o.wavelengths_um.size(),
          "needs one weight per wavelength (" + std::to_string(o.wavelengths_um.size()) + "), got " +
              std::to_string(o.spectral_weights.size()));
  for (double wavelength_um : o.wavelengths_um)
    f.check("wavelengths_um", wavelength_um <= 20.0, "wavelengths are in micrometres (got > 20)");
  f.section("sun_disk", Layout::kFlow, Presence::kOptional, [&] {
    f.flag("enabled", o.sun.enabled);
    f.number("angular_diameter_deg", o.sun.angular_diameter_deg, Bound::kPositive);
    f.number("limb_darkening_u", o.sun.limb_darkening_u, Bound::kFraction);
  });
  f.flag("vignetting", o.vignetting);
  f.number("grid_step_um", o.grid_step_um, Bound::kPositive);
  const std::string grid_rule =
      "must be a power of two in [32, " + std::to_string(limits::kMaxDiffractionGrid) + "] (limit)";
  f.integer("grid_size", o.grid_size, 32, limits::kMaxDiffractionGrid, grid_rule);
  f.check("grid_size", (o.grid_size & (o.grid_size - 1)) == 0, grid_rule);
  f.number("psf_node_step_deg", o.psf_node_step_deg, Bound::kPositive);
}

template <typename Fields>
void detectorNoiseFields(Fields& f, DetectorNoiseConfig& n) {
  f.flag("shot_noise", n.shot_noise);
  f.number("read_noise_e", n.read_noise_e, Bound::kNonNegative);
  f.number("full_well_e", n.full_well_e, Bound::kPositive, kRequired);
  f.number("adc_full_scale_e", n.adc_full_scale_e, Bound::kPositive, n.full_well_e);
  f.integer("bit_depth", n.bit_depth, 1, 16, "must be in [1, 16]");
  f.number("black_level_dn", n.black_level_dn, Bound::kNonNegative);
  f.number("dark_current_e_per_s", n.dark_current_e_per_s, Bound::kNonNegative);
  f.number("dark_reference_temp_c", n.dark_reference_temp_c, Bound::kAny);
  f.number("dark_doubling_temp_c", n.dark_doubling_temp_c, Bound::kPositive);
  f.number("temperature_c", n.temperature_c, Bound::kAny);
  f.check("temperature_c", n.temperature_c >= -273.15, "below absolute zero");
  f.number("dsnu_fraction", n.dsnu_fraction, Bound::kNonNegative);
  f.number("prnu_fraction", n.prnu_fraction, Bound::kNonNegative);
}

template <typename Fields>
void anomalyFields(Fields& f, AnomalyConfig& an, const DetectorConfig& detector) {
  f.section("stray_light", Layout::kFlow, Presence::kOptional, [&] {
    f.number("probability", an.stray_light_probability, Bound::kFraction);
    f.number("max_fraction", an.stray_light_max_fraction, Bound::kNonNegative);
  });
  f.section("hot_pixels", Layout::kFlow, Presence::kOptional, [&] {
    f.integer("count", an.hot_pixel_count, 0, std::int64_t{detector.width_px} * detector.height_px,
              "must be in [0, the detector's pixel count]");
    f.number("min_e_per_s", an.hot_pixel_min_e_per_s, Bound::kPositive);
    f.number("max_e_per_s", an.hot_pixel_max_e_per_s, Bound::kPositive);
    f.check("max_e_per_s", an.hot_pixel_max_e_per_s >= an.hot_pixel_min_e_per_s, "must be >= min_e_per_s");
  });
  f.section("debris", Layout::kFlow, Presence::kOptional, [&] {
    f.number("probability", an.debris_probability, Bound::kFraction);
    f.number("max_blocked_fraction", an.debris_max_blocked_fraction, Bound::kFraction);
  });
  f.section("ghost", Layout::kFlow, Presence::kOptional, [&] {
    f.number("probability", an.ghost_probability, Bound::kFraction);
    f.number("reflectance", an.ghost_reflectance, Bound::kFraction);
  });
}

template <typename Fields>
void sensorConfigFields(Fields& f, SensorConfig& c) {
  f.text("name", c.name, kRequired);
  f.section("detector", Layout::kFlow, Presence::kRequired, [&] {
    const std::string side_rule = "must be in [8, " + std::to_string(limits::kMaxDetectorSidePx) + "] (limit)";
    f.integer("width_px", c.detector.width_px, 8, limits::kMaxDetectorSidePx, side_rule, kRequired);
    f.integer("height_px", c.detector.height_px, 8, limits::kMaxDetectorSidePx, side_rule, kRequired);
    f.number("pitch_um", c.detector.pitch_um, Bound::kPositive, kRequired);
  });
  f.section("mask", Layout::kBlock, Presence::kRequired, [&] {
    f.number("height_mm", c.mask.height_mm, Bound::kPositive, kRequired);
    f.number("thickness_mm", c.mask.thickness_mm, Bound::kNonNegative);
    f.items("apertures", c.mask.apertures, limits::kMaxApertures, "apertures", Layout::kFlow,
            [&](ApertureConfig& a) { apertureFields(f, a); });
  });
  f.section("cover_glass", Layout::kFlow, Presence::kOptional, [&] {
    f.flag("enabled", c.cover_glass.enabled);
    f.number("thickness_mm", c.cover_glass.thickness_mm, Bound::kNonNegative);
    f.number("refractive_index", c.cover_glass.refractive_index, Bound::kAny);
    f.check("refractive_index", c.cover_glass.refractive_index >= 1.0, "must be >= 1");
    f.check("thickness_mm", !c.cover_glass.enabled || c.cover_glass.thickness_mm <= c.mask.height_mm,
            "cover glass is thicker than the mask height");
  });
  f.section("optics", Layout::kBlock, Presence::kRequired, [&] { opticsFields(f, c.optics); });
  f.section("radiometry", Layout::kFlow, Presence::kOptional, [&] {
    f.number("irradiance_w_m2", c.radiometry.irradiance_w_m2, Bound::kPositive);
    f.number("nd_transmission", c.radiometry.nd_transmission, Bound::kPositive);
    f.number("quantum_efficiency", c.radiometry.quantum_efficiency, Bound::kPositive);
    f.check("quantum_efficiency", c.radiometry.quantum_efficiency <= 1.0, "must be <= 1");
  });
  f.section("exposure", Layout::kFlow, Presence::kOptional, [&] {
    f.choice("mode", c.exposure.mode, {{"auto", ExposureMode::kAuto}, {"fixed", ExposureMode::kFixed}},
             "exposure mode");
    f.number("peak_fraction_of_full_well", c.exposure.peak_fraction_of_full_well, Bound::kPositive);
    f.number("exposure_s", c.exposure.exposure_s, Bound::kPositive);
  });
  f.section("detector_noise", Layout::kBlock, Presence::kRequired, [&] { detectorNoiseFields(f, c.noise); });
  f.section("threshold", Layout::kFlow, Presence::kOptional, [&] {
    f.flag("enabled", c.threshold.enabled);
    f.number("level_fraction", c.threshold.level_fraction, Bound::kFraction);
    f.check("level_fraction", c.threshold.level_fraction < 1.0, "must be < 1");
    f.flag("rescale", c.threshold.rescale);
  });
  f.section("as_built", Layout::kFlow, Presence::kOptional, [&] {
    f.number("height_sigma_um", c.as_built.height_sigma_um, Bound::kNonNegative);
    f.number("offset_sigma_um", c.as_built.offset_sigma_um, Bound::kNonNegative);
    f.number("rotation_sigma_deg", c.as_built.rotation_sigma_deg, Bound::kNonNegative);
    f.number("tilt_sigma_deg", c.as_built.tilt_sigma_deg, Bound::kNonNegative);
    f.number("aperture_position_sigma_um", c.as_built.aperture_position_sigma_um, Bound::kNonNegative);
    f.number("aperture_diameter_sigma_um", c.as_built.aperture_diameter_sigma_um, Bound::kNonNegative);
  });
  f.section("anomalies", Layout::kBlock, Presence::kOptional, [&] { anomalyFields(f, c.anomalies, c.detector); });
  f.section("fov", Layout::kFlow, Presence::kRequired, [&] {
    f.number("alpha_max_deg", c.fov.alpha_max_deg, Bound::kPositive, kRequired);
    f.number("beta_max_deg", c.fov.beta_max_deg, Bound::kPositive, kRequired);
    f.check("alpha_max_deg", c.fov.alpha_max_deg < 89.0 && c.fov.beta_max_deg < 89.0, "must be < 89");
  });
  if (c.optics.mode == OpticsMode::kFresnel) {
    // The simulator caches a diffraction pattern per node over the field.
    const double step = c.optics.psf_node_step_deg;
    const double nodes = (2.0 * c.fov.alpha_max_deg / step + 2.0) * (2.0 * c.fov.beta_max_deg / step + 2.0);
    f.check("optics.psf_node_step_deg", nodes <= static_cast<double>(limits::kMaxPsfNodes),
            std::to_string(step) + " deg gives " + std::to_string(static_cast<long long>(nodes)) +
                " diffraction nodes over the field of view, over the limit of " + std::to_string(limits::kMaxPsfNodes));
  }
  f.choice("subfov", c.subfov,
           {{"quadrant", SubFovType::kQuadrant}, {"nearest_aperture", SubFovType::kNearestAperture}}, "sub-FOV scheme");
}

}  // namespace dss
