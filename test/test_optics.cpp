// Optics against closed forms: Airy far field, geometric shadow, energy
// conservation, spot centre at h tan(theta) (with and without cover glass);
// the spot cache's blend composed into one map.
#include <gtest/gtest.h>

#include <cmath>

#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/sim/geometry.h"
#include "digital_sun_sensor/sim/optics.h"
#include "digital_sun_sensor/sim/spot_cache.h"

namespace dss {
namespace {

OpticalPath monochromatic(double z_um, double lambda_um, double step_um, int grid) {
  OpticalPath p;
  p.air_gap_um = z_um;
  p.wavelengths_um = {lambda_um};
  p.weights = {1.0};
  p.sun.enabled = false;
  p.vignetting = false;
  p.step_um = step_um;
  p.grid_size = grid;
  p.pitch_um = 1.55;
  return p;
}

ApertureGeometry circle(double d_um) {
  ApertureGeometry a;
  a.diameter_um = d_um;
  return a;
}

SpotMapOptions raw() {
  SpotMapOptions o;
  o.sun_disk = false;
  o.pixel_integration = false;
  o.crop = false;
  return o;
}

// Irradiance (not pixel power) of a raw map at offset (u, v).
double irradiance(const SpotMap& m, const OpticalPath& p, double u, double v) {
  return m.sample(u, v) / (p.pitch_um * p.pitch_um);
}

TEST(Optics, FarFieldMatchesAiryPattern) {
  // Fresnel number a^2 / (lambda z) = 0.036: the angular spectrum result must
  // approach the Fraunhofer (Airy) pattern.
  const double d = 20.0, z = 5000.0, lambda = 0.55;
  const OpticalPath p = monochromatic(z, lambda, 1.0, 1024);
  const SpotMap m = computeSpotMap(circle(d), Eigen::Vector3d::UnitZ(), p, raw());
  const double peak = airyIrradiance(0.0, d, lambda, z);
  double worst = 0.0;
  for (double r = 0.0; r <= 350.0; r += 1.0) {
    worst = std::max(worst, std::abs(irradiance(m, p, r, 0.0) - airyIrradiance(r, d, lambda, z)));
    worst = std::max(worst, std::abs(irradiance(m, p, 0.0, -r) - airyIrradiance(r, d, lambda, z)));
  }
  EXPECT_LT(worst / peak, 0.01) << "max deviation from Airy, fraction of peak";
  // First dark ring at 1.22 lambda z / D.
  const double r0 = 1.22 * lambda * z / d;
  EXPECT_LT(irradiance(m, p, r0, 0.0) / peak, 0.005);
}

TEST(Optics, LargeFresnelNumberGivesGeometricShadow) {
  // a^2 / (lambda z) = 200: the spot is the aperture's shadow.
  const double d = 200.0, z = 100.0, lambda = 0.5;
  const OpticalPath p = monochromatic(z, lambda, 0.5, 1024);
  const SpotMap m = computeSpotMap(circle(d), Eigen::Vector3d::UnitZ(), p, raw());
  double inner_sum = 0.0, inside_power = 0.0, total = 0.0, outside_max = 0.0;
  int inner_n = 0;
  for (int r = 0; r < m.rows; ++r) {
    for (int c = 0; c < m.cols; ++c) {
      const double u = m.u0_um + c * m.step_um, v = m.v0_um + r * m.step_um;
      const double rho = std::hypot(u, v);
      const double e = m.values[r * m.cols + c] / (p.pitch_um * p.pitch_um);
      total += e;
      if (rho < 0.7 * d / 2) inner_sum += e, ++inner_n;
      if (rho < d / 2) inside_power += e;
      if (rho > 1.3 * d / 2) outside_max = std::max(outside_max, e);
    }
  }
  EXPECT_NEAR(inner_sum / inner_n, 1.0, 0.03);
  EXPECT_GT(inside_power / total, 0.98);
  EXPECT_LT(outside_max, 0.02);
}

TEST(Optics, EnergyIsConserved) {
  // Propagation, solar disk and pixel integration each preserve power.
  const double d = 100.0;
  OpticalPath p = monochromatic(1000.0, 0.55, 1.0, 1024);
  const double area = circle(d).nominalAreaUm2();
  const SpotMap bare = computeSpotMap(circle(d), Eigen::Vector3d::UnitZ(), p, raw());
  EXPECT_NEAR(bare.total_power_um2 / area, 1.0, 0.01);
  p.sun.enabled = true;
  SpotMapOptions all;
  all.crop = false;
  const SpotMap filtered = computeSpotMap(circle(d), Eigen::Vector3d::UnitZ(), p, all);
  EXPECT_NEAR(filtered.total_power_um2 / bare.total_power_um2, 1.0, 0.002);
  // Oblique incidence: power through the aperture scales with cos(theta).
  const Eigen::Vector3d oblique = sunVectorFromAngles(4.0 * kRadPerDeg, -3.0 * kRadPerDeg);
  const SpotMap tilted = computeSpotMap(circle(d), oblique, p, all);
  EXPECT_NEAR(tilted.total_power_um2 / (area * oblique.z()), 1.0, 0.01);
}

// Power-weighted centroid of a map relative to the geometric spot centre [um].
Eigen::Vector2d centroid(const SpotMap& m) {
  double su = 0, sv = 0, s = 0;
  for (int r = 0; r < m.rows; ++r) {
    for (int c = 0; c < m.cols; ++c) {
      const double w = m.values[r * m.cols + c];
      su += w * (m.u0_um + c * m.step_um);
      sv += w * (m.v0_um + r * m.step_um);
      s += w;
    }
  }
  return {su / s, sv / s};
}

TEST(Optics, SpotCentreAtHeightTimesTangent) {
  // Geometry: the detector hit point of the aperture centre is -h tan(theta).
  const double h = 5000.0;
  const Eigen::Vector3d sun = sunVectorFromAngles(3.0 * kRadPerDeg, -2.0 * kRadPerDeg);
  const auto hit = traceToDetector(Eigen::Vector3d(0, 0, h), sun, {});
  ASSERT_TRUE(hit);
  EXPECT_NEAR(hit->x(), -h * std::tan(3.0 * kRadPerDeg), 1e-9);
  EXPECT_NEAR(hit->y(), h * std::tan(2.0 * kRadPerDeg), 1e-9);
  // Diffraction: the light's centroid lands there (maps are relative to it),
  // polychromatic, with the solar disk and pixel integration.
  OpticalPath p = monochromatic(h, 0.55, 1.0, 512);
  p.wavelengths_um = {0.45, 0.506, 0.55, 0.6, 0.65};
  p.weights = {0.444 / 3.276, 1.0 / 3.276, 0.788 / 3.276, 0.688 / 3.276, 0.356 / 3.276};
  p.sun.enabled = true;
  SpotMapOptions o;
  o.crop = false;
  const Eigen::Vector2d c = centroid(computeSpotMap(circle(100.0), sun, p, o));
  EXPECT_LT(c.norm() / p.pitch_um, 0.02) << "centroid offset " << c.transpose() << " um";
}

TEST(Optics, SpotCentreWithCoverGlassFollowsSnell) {
  const double h = 5000.0, t = 1000.0, n = 1.5;
  const double theta = 4.0 * kRadPerDeg;
  const Eigen::Vector3d sun = sunVectorFromAngles(theta, 0.0);
  const auto hit = traceToDetector(Eigen::Vector3d(0, 0, h), sun, {t, n});
  ASSERT_TRUE(hit);
  const double theta_glass = std::asin(std::sin(theta) / n);
  EXPECT_NEAR(hit->x(), -(h - t) * std::tan(theta) - t * std::tan(theta_glass), 1e-9);
  EXPECT_NEAR(hit->y(), 0.0, 1e-12);
  // The diffracted light's centroid follows the refracted ray.
  OpticalPath p = monochromatic(h - t, 0.55, 1.0, 512);
  p.glass_um = t;
  p.glass_index = n;
  SpotMapOptions o;
  o.crop = false;
  const Eigen::Vector2d c = centroid(computeSpotMap(circle(100.0), sun, p, o));
  EXPECT_LT(c.norm() / p.pitch_um, 0.02) << "centroid offset " << c.transpose() << " um";
}

TEST(Optics, VignettingShiftsCentroidByHalfThicknessTangent) {
  // The mask's two faces clip the beam: the open area's centre moves by
  // t tan(theta) / 2 toward the spot's direction of motion.
  const double h = 5000.0, t = 30.0, theta = 4.0 * kRadPerDeg;
  OpticalPath p = monochromatic(h, 0.55, 1.0, 512);
  p.vignetting = true;
  p.mask_thickness_um = t;
  SpotMapOptions o;
  o.crop = false;
  const Eigen::Vector2d c = centroid(computeSpotMap(circle(100.0), sunVectorFromAngles(theta, 0.0), p, o));
  EXPECT_NEAR(c.x(), -0.5 * t * std::tan(theta), 0.1 * 0.5 * t * std::tan(theta));
}

TEST(SpotCache, ComposedBlendSamplesAsTheWeightedMaps) {
  // Four cropped nodes of different extents around an oblique incidence
  // (the renderer composes them once for every aperture of one shape).
  OpticalPath p = monochromatic(2000.0, 0.55, 1.0, 256);
  p.vignetting = true;
  p.mask_thickness_um = 20.0;
  SpotCache cache(p, 1.0);
  const SpotCache::Blend blend = cache.lookup(circle(60.0), sunVectorFromAngles(2.3 * kRadPerDeg, -1.6 * kRadPerDeg));
  ASSERT_EQ(blend.count, 4);
  const SpotMap one = blend.composed();
  double worst = 0.0, peak = 0.0, power = 0.0;
  for (int k = 0; k < blend.count; ++k) power += blend.weights[k] * blend.maps[k]->total_power_um2;
  for (double v = -150.0; v <= 150.0; v += 1.37)
    for (double u = -150.0; u <= 150.0; u += 1.37) {
      double sum = 0.0;
      for (int k = 0; k < blend.count; ++k) sum += blend.weights[k] * blend.maps[k]->sample(u, v);
      worst = std::max(worst, std::abs(one.sample(u, v) - sum));
      peak = std::max(peak, sum);
    }
  ASSERT_GT(peak, 0.0);
  EXPECT_LT(worst / peak, 1e-5);
  EXPECT_NEAR(one.total_power_um2, power, 1e-9 * power);
}

TEST(SpotCache, ComposedBlendOfMapsOnOneLatticeIsTheirWeightedSum) {
  // Maps on the same samples (uncropped nodes, as thesis_ca's) take the
  // one-pass path: each sample the weighted sum in the order of the maps,
  // as the general path adds them, to the bit.
  SpotMap a;
  a.cols = 37, a.rows = 5, a.step_um = 1.0, a.u0_um = -18.0, a.v0_um = -2.0;
  for (int i = 0; i < a.cols * a.rows; ++i) a.values.push_back(0.001f * static_cast<float>((i * 7919) % 1013));
  a.total_power_um2 = 2.0;
  SpotMap b = a;
  for (float& v : b.values) v = 1.3f - v;
  b.total_power_um2 = 3.0;
  SpotCache::Blend blend;
  blend.maps = {std::make_shared<const SpotMap>(a), std::make_shared<const SpotMap>(b),
                std::make_shared<const SpotMap>(a)};
  blend.weights = {0.3f, 0.6f, 0.1f};
  blend.count = 3;
  const SpotMap one = blend.composed();
  ASSERT_EQ(one.values.size(), a.values.size());
  for (std::size_t i = 0; i < a.values.size(); ++i) {
    float expected = 0.0f;
    expected += 0.3f * a.values[i];
    expected += 0.6f * b.values[i];
    expected += 0.1f * a.values[i];
    ASSERT_EQ(one.values[i], expected) << "sample " << i;
  }
  EXPECT_DOUBLE_EQ(one.total_power_um2, blend.weights[0] * 2.0 + blend.weights[1] * 3.0 + blend.weights[2] * 2.0);
  EXPECT_EQ(one.u0_um, a.u0_um);
  EXPECT_EQ(one.cols, a.cols);
}

// The process's cache memory limit as it was, again at the end of a test.
struct RestoredMemoryLimit {
  std::size_t bytes = SpotCache::memoryLimitBytes();
  ~RestoredMemoryLimit() { SpotCache::setMemoryLimitBytes(bytes); }
};

TEST(SpotCache, HoldsNoMoreThanItsMemoryLimitAndRecomputesTheSameMaps) {
  OpticalPath p = monochromatic(2000.0, 0.55, 1.0, 128);
  SpotCache cache(p, 1.0);
  const Eigen::Vector3d sun = sunVectorFromAngles(0.4 * kRadPerDeg, -0.3 * kRadPerDeg);
  const SpotMap first = cache.lookup(circle(60.0), sun).composed();
  ASSERT_EQ(cache.nodesHeld(), 4u);
  // Room for this cache's four maps and two more, whatever else the process holds.
  const RestoredMemoryLimit restore;
  const std::size_t limit = SpotCache::memoryHeldBytes() + cache.bytesHeld() / 2;
  SpotCache::setMemoryLimitBytes(limit);
  for (double diameter : {50.0, 40.0, 30.0}) {  // other shapes: four new maps each
    cache.lookup(circle(diameter), sun);
    EXPECT_LE(SpotCache::memoryHeldBytes(), limit) << diameter;
  }
  EXPECT_GE(cache.nodesDropped(), 4u);
  const SpotMap again = cache.lookup(circle(60.0), sun).composed();  // its maps were dropped: computed again
  EXPECT_EQ(again.values, first.values);
  EXPECT_EQ(again.total_power_um2, first.total_power_um2);
}

// The limit holds over every cache together, by their maps' last use: a
// cache that adds maps past it drops another's older maps, not its own
// newer ones (dropping only the adder's own let an idle cache, another
// renderer in the process, keep all of its while the adder dropped maps
// its image still needed).
TEST(SpotCache, DropsTheLeastRecentlyUsedMapsOfAnyCache) {
  SpotCache idle(monochromatic(2000.0, 0.55, 1.0, 128), 1.0), busy(monochromatic(2000.0, 0.60, 1.0, 128), 1.0);
  const Eigen::Vector3d sun = sunVectorFromAngles(0.4 * kRadPerDeg, -0.3 * kRadPerDeg);
  idle.lookup(circle(60.0), sun);
  ASSERT_EQ(idle.nodesHeld(), 4u);
  const RestoredMemoryLimit restore;
  // Room for two more maps than every cache holds now.
  const std::size_t limit = SpotCache::memoryHeldBytes() + idle.bytesHeld() / 2;
  SpotCache::setMemoryLimitBytes(limit);
  busy.lookup(circle(60.0), sun);
  EXPECT_LE(SpotCache::memoryHeldBytes(), limit);
  EXPECT_EQ(busy.nodesDropped(), 0u);  // the idle cache's maps went first
  EXPECT_GT(idle.nodesDropped(), 0u);
  busy.lookup(circle(50.0), sun);  // four more
  EXPECT_LE(SpotCache::memoryHeldBytes(), limit);
  EXPECT_TRUE(idle.nodesHeld() == 0 || busy.nodesDropped() == 0)
      << "the busy cache dropped a map before the idle one's older ones";
  const std::size_t busy_dropped = busy.nodesDropped();
  idle.lookup(circle(60.0), sun);  // computed again: now the busy cache's maps are the older ones
  EXPECT_LE(SpotCache::memoryHeldBytes(), limit);
  EXPECT_EQ(idle.nodesHeld(), 4u);
  EXPECT_GT(busy.nodesDropped(), busy_dropped);
}

}  // namespace
}  // namespace dss
