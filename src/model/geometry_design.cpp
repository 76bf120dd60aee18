#include "digital_sun_sensor/model/geometry_design.h"

#include <algorithm>
#include <cmath>
#include <numeric>

#include "digital_sun_sensor/sim/random_mask.h"

namespace dss {

int GeometryDesign::groupCount() const {
  if (groups.empty()) return static_cast<int>(apertures_um.size());
  return *std::max_element(groups.begin(), groups.end()) + 1;
}

namespace {

double largestDiameterUm(const SensorConfig& config) {
  double largest = 0.0;
  for (const auto& a : config.mask.apertures) largest = std::max(largest, a.equivalentDiameterUm());
  return largest;
}

}  // namespace

GeometryDesign geometryDesignOf(const SensorConfig& config) {
  GeometryDesign d;
  // The light a hole in a mask of thickness t passes is centred on its
  // mid-plane: at oblique incidence the walls clip one side at the entrance
  // and the other at the exit (the baseline's fitted height absorbs the
  // same t / 2).
  d.height_um = (config.mask.height_mm + 0.5 * config.mask.thickness_mm) * 1000.0;
  d.air_above_exit_um = 0.5 * config.mask.thickness_mm * 1000.0;
  if (config.cover_glass.enabled) {
    d.glass_thickness_um = config.cover_glass.thickness_mm * 1000.0;
    d.glass_index = config.cover_glass.refractive_index;
  }
  const std::size_t n = config.mask.apertures.size();
  for (const auto& a : config.mask.apertures) {
    d.apertures_um.push_back({a.x_um, a.y_um});
    d.fluxes.push_back(a.areaUm2());
  }
  // Union-find over the pairs closer than a spot diameter, then groups
  // numbered in the order of their first aperture.
  const double overlap_um = spotDiameterUm(config, largestDiameterUm(config));
  std::vector<std::size_t> parent(n);
  std::iota(parent.begin(), parent.end(), 0);
  auto root = [&](std::size_t i) {
    while (parent[i] != i) i = parent[i] = parent[parent[i]];
    return i;
  };
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t j = 0; j < i; ++j)
      if (std::hypot(d.apertures_um[i][0] - d.apertures_um[j][0], d.apertures_um[i][1] - d.apertures_um[j][1]) <
          overlap_um)
        parent[root(i)] = root(j);
  std::vector<int> number(n, -1);
  int groups = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t r = root(i);
    if (number[r] < 0) number[r] = groups++;
    d.groups.push_back(number[r]);
  }
  return d;
}

double geometricGateUm(const SensorConfig& config, const GeometryDesign& design) {
  double gate = 2.0 * spotDiameterUm(config, largestDiameterUm(config));
  for (std::size_t i = 0; i < design.apertures_um.size(); ++i)
    for (std::size_t j = 0; j < i; ++j)
      if (design.groups[i] != design.groups[j])
        gate = std::min(gate, 0.5 * std::hypot(design.apertures_um[i][0] - design.apertures_um[j][0],
                                               design.apertures_um[i][1] - design.apertures_um[j][1]));
  return gate;
}

}  // namespace dss
