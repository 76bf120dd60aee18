// Sun angles, sun vectors, and the ray geometry from an aperture to the detector.
// Frame: sun_sensor_link, +z boresight (toward the sky), +x along detector
// columns, +y along rows. The sun vector s points from the sensor to the sun.
#pragma once

#include <Eigen/Core>

#include <optional>

namespace dss {

struct SunAnglesRad {
  double alpha = 0.0;  // atan2(s_x, s_z)
  double beta = 0.0;   // atan2(s_y, s_z)
};

// Unit sun vector for angles (alpha, beta); s_z > 0 for |alpha|, |beta| < 90 deg.
Eigen::Vector3d sunVectorFromAngles(double alpha_rad, double beta_rad);
SunAnglesRad anglesFromSunVector(const Eigen::Vector3d& sun);

// Quadrant class: 0 (a<0,b<0), 1 (a>=0,b<0), 2 (a<0,b>=0), 3 (a>=0,b>=0).
int quadrantClass(double alpha_rad, double beta_rad);

// Where the sunlight passing through `aperture_m` (sensor frame, metres...
// here micrometres) reaches the detector plane z = 0, with an optional cover
// glass slab (thickness, index) lying on the detector. Returns nullopt when
// the sun is at or below the mask plane. Exact Snell refraction.
struct GlassSlab {
  double thickness_um = 0.0;
  double refractive_index = 1.0;
};
std::optional<Eigen::Vector2d> traceToDetector(const Eigen::Vector3d& aperture_um, const Eigen::Vector3d& sun,
                                               const GlassSlab& glass);

// Jacobian of the detector hit point with respect to a small rotation of the
// sun direction, d(hit_um)/d(delta_rad) for delta about the two axes
// perpendicular to the sun vector. Used to project the solar disk.
Eigen::Matrix2d sunDiskJacobian(double height_um, const Eigen::Vector3d& sun, const GlassSlab& glass);

}  // namespace dss
