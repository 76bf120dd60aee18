// One physical sensor: the nominal design plus its manufacturing errors,
// contamination and detector fixed patterns, drawn once per sensor from a
// seed. The estimator never sees these; calibration exists because of them.
#pragma once

#include "digital_sun_sensor/sim/sensor_config.h"

#include <Eigen/Core>

#include <cstdint>
#include <vector>

namespace dss {

struct HotPixel {
  int index = 0;             // row * width + col
  float dark_e_per_s = 0.0f;
};

// Mask attitude: rotation about the boresight, then tilts about x and y.
Eigen::Matrix3d maskRotation(double rotation_rad, double tilt_x_rad, double tilt_y_rad);

struct SensorInstance {
  SensorConfig config;
  std::uint64_t seed = 0;
  bool nominal = true;

  // Mask pose in the sensor frame: rotation (about z, then tilt) and offset.
  Eigen::Matrix3d mask_rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d mask_offset_um = Eigen::Vector3d::Zero();  // z: height error
  std::vector<ApertureConfig> apertures;  // as built, with debris occluders

  // Detector fixed patterns (empty = uniform).
  std::vector<float> prnu_gain;   // per-pixel gain factor, mean 1
  std::vector<float> dark_scale;  // per-pixel dark current factor, mean 1
  std::vector<HotPixel> hot_pixels;

  // Aperture centre (exit face) in the sensor frame [um].
  Eigen::Vector3d apertureCentreUm(std::size_t i) const;

  // The design as drawn: no errors, no debris, uniform detector.
  static SensorInstance nominalOf(const SensorConfig& config);
  // A random draw of every per-sensor error the config enables.
  static SensorInstance draw(const SensorConfig& config, std::uint64_t seed);
};

}  // namespace dss
