#include "digital_sun_sensor/sim/sensor_instance.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/common/units.h"

namespace dss {
namespace {

// Radius of an occluding disk whose centre sits at distance `d` from the centre
// of a circular aperture of radius `a`, chosen so that it blocks `fraction`
// of the aperture (bisection on the lens-area formula).
double occluderRadiusFor(double a, double d, double fraction) {
  auto blocked = [&](double r) {
    if (d >= a + r) return 0.0;
    if (d + a <= r) return 1.0;
    if (d + r <= a) return (r * r) / (a * a);
    const double alpha = std::acos((d * d + a * a - r * r) / (2 * d * a));
    const double beta = std::acos((d * d + r * r - a * a) / (2 * d * r));
    const double lens = a * a * alpha + r * r * beta -
                        0.5 * std::sqrt(std::max(0.0, (-d + a + r) * (d + a - r) * (d - a + r) * (d + a + r)));
    return lens / (M_PI * a * a);
  };
  double lo = 0.0, hi = 3.0 * a;
  for (int i = 0; i < 60; ++i) {
    const double mid = 0.5 * (lo + hi);
    (blocked(mid) < fraction ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

}  // namespace

Eigen::Matrix3d maskRotation(double rotation_rad, double tilt_x_rad, double tilt_y_rad) {
  return (Eigen::AngleAxisd(tilt_y_rad, Eigen::Vector3d::UnitY()) *
          Eigen::AngleAxisd(tilt_x_rad, Eigen::Vector3d::UnitX()) *
          Eigen::AngleAxisd(rotation_rad, Eigen::Vector3d::UnitZ()))
      .toRotationMatrix();
}

Eigen::Vector3d SensorInstance::apertureCentreUm(std::size_t i) const {
  const auto& a = apertures.at(i);
  return mask_rotation * Eigen::Vector3d(a.x_um, a.y_um, 0.0) + mask_offset_um +
         Eigen::Vector3d(0.0, 0.0, config.mask.height_mm * 1000.0);
}

SensorInstance SensorInstance::nominalOf(const SensorConfig& config) {
  SensorInstance s;
  s.config = config;
  s.apertures = config.mask.apertures;
  return s;
}

SensorInstance SensorInstance::draw(const SensorConfig& config, std::uint64_t seed) {
  SensorInstance s = nominalOf(config);
  s.seed = seed;
  s.nominal = false;
  const auto& ab = config.as_built;
  Rng rng(deriveSeed(seed, 0xA5B1));

  const double rot = rng.normal() * ab.rotation_sigma_deg * kRadPerDeg;
  const double tilt_x = rng.normal() * ab.tilt_sigma_deg * kRadPerDeg;
  const double tilt_y = rng.normal() * ab.tilt_sigma_deg * kRadPerDeg;
  s.mask_rotation = maskRotation(rot, tilt_x, tilt_y);
  s.mask_offset_um = Eigen::Vector3d(rng.normal() * ab.offset_sigma_um, rng.normal() * ab.offset_sigma_um,
                                     rng.normal() * ab.height_sigma_um);
  for (auto& a : s.apertures) {
    a.x_um += rng.normal() * ab.aperture_position_sigma_um;
    a.y_um += rng.normal() * ab.aperture_position_sigma_um;
    const double dd = rng.normal() * ab.aperture_diameter_sigma_um;
    if (a.shape == ApertureShape::kCircle) {
      a.diameter_um = std::max(0.2 * a.diameter_um, a.diameter_um + dd);
    } else {
      a.width_um = std::max(0.2 * a.width_um, a.width_um + dd);
      a.height_um = std::max(0.2 * a.height_um, a.height_um + dd);
    }
  }

  // Debris: an opaque disk from the rim inward, blocking up to the max fraction.
  const auto& an = config.anomalies;
  Rng debris_rng(deriveSeed(seed, 0xDEB));
  for (auto& a : s.apertures) {
    if (debris_rng.uniform() >= an.debris_probability) continue;
    const double radius =
        a.shape == ApertureShape::kCircle ? 0.5 * a.diameter_um : 0.5 * std::min(a.width_um, a.height_um);
    const double fraction = debris_rng.uniform(0.02, std::max(0.021, an.debris_max_blocked_fraction));
    const double angle = debris_rng.uniform(0.0, 2.0 * M_PI);
    const double d = radius;  // centred on the rim
    const double r = occluderRadiusFor(radius, d, fraction);
    a.occluders.push_back({d * std::cos(angle), d * std::sin(angle), r});
  }

  // Detector fixed patterns.
  const int n_px = config.detector.width_px * config.detector.height_px;
  Rng fpn(deriveSeed(seed, 0xF9A));
  if (config.noise.prnu_fraction > 0.0) {
    s.prnu_gain.resize(n_px);
    for (auto& g : s.prnu_gain) g = static_cast<float>(std::max(0.0, 1.0 + config.noise.prnu_fraction * fpn.normal()));
  }
  if (config.noise.dsnu_fraction > 0.0) {
    s.dark_scale.resize(n_px);
    for (auto& d : s.dark_scale) d = static_cast<float>(std::max(0.0, 1.0 + config.noise.dsnu_fraction * fpn.normal()));
  }
  Rng hot(deriveSeed(seed, 0x407));
  const double log_lo = std::log(an.hot_pixel_min_e_per_s), log_hi = std::log(an.hot_pixel_max_e_per_s);
  for (int i = 0; i < an.hot_pixel_count; ++i) {
    s.hot_pixels.push_back(
        {static_cast<int>(hot.below(n_px)), static_cast<float>(std::exp(hot.uniform(log_lo, log_hi)))});
  }
  return s;
}

}  // namespace dss
