#include "digital_sun_sensor/sim/geometry.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

namespace dss {

Eigen::Vector3d sunVectorFromAngles(double alpha_rad, double beta_rad) {
  // tan(alpha) = s_x / s_z, tan(beta) = s_y / s_z.
  Eigen::Vector3d s(std::tan(alpha_rad), std::tan(beta_rad), 1.0);
  return s.normalized();
}

SunAnglesRad anglesFromSunVector(const Eigen::Vector3d& sun) {
  return {std::atan2(sun.x(), sun.z()), std::atan2(sun.y(), sun.z())};
}

int quadrantClass(double alpha_rad, double beta_rad) { return (alpha_rad >= 0.0 ? 1 : 0) + (beta_rad >= 0.0 ? 2 : 0); }

std::optional<Eigen::Vector2d> traceToDetector(const Eigen::Vector3d& aperture_um, const Eigen::Vector3d& sun,
                                               const GlassSlab& glass) {
  const Eigen::Vector3d s = sun.normalized();
  if (s.z() <= 1e-9) return std::nullopt;
  if (aperture_um.z() < 0.0) return std::nullopt;
  // A mask resting on the glass with a negative height error sits on a
  // thinner slab: the glass never extends above the aperture.
  const double glass_um = std::min(glass.thickness_um, aperture_um.z());
  const double air_um = aperture_um.z() - glass_um;
  // The light travels along -s: lateral drift per unit drop is s_xy / s_z.
  Eigen::Vector2d hit = aperture_um.head<2>() - air_um * s.head<2>() / s.z();
  if (glass_um > 0.0) {
    const double sin_air = s.head<2>().norm();
    const double sin_glass = sin_air / glass.refractive_index;
    const double cos_glass = std::sqrt(1.0 - sin_glass * sin_glass);
    if (sin_air > 0.0) hit -= glass_um * (sin_glass / cos_glass) * s.head<2>() / sin_air;
  }
  return hit;
}

Eigen::Matrix2d sunDiskJacobian(double height_um, const Eigen::Vector3d& sun, const GlassSlab& glass) {
  const Eigen::Vector3d s = sun.normalized();
  // Two unit axes perpendicular to s.
  Eigen::Vector3d e1 = s.cross(Eigen::Vector3d::UnitY());
  if (e1.norm() < 1e-6) e1 = s.cross(Eigen::Vector3d::UnitX());
  e1.normalize();
  const Eigen::Vector3d e2 = s.cross(e1).normalized();
  const Eigen::Vector3d ap(0.0, 0.0, height_um);
  const double d = 1e-6;
  Eigen::Matrix2d j;
  const auto centre = traceToDetector(ap, s, glass);
  for (int k = 0; k < 2; ++k) {
    const Eigen::Vector3d axis = (k == 0 ? e1 : e2);
    const auto plus = traceToDetector(ap, (s + d * axis).normalized(), glass);
    const auto minus = traceToDetector(ap, (s - d * axis).normalized(), glass);
    if (!centre || !plus || !minus) return Eigen::Matrix2d::Zero();
    j.col(k) = (*plus - *minus) / (2.0 * d);
  }
  return j;
}

}  // namespace dss
