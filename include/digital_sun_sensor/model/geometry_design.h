// A sensor design as the geometric head takes it (torch-free): the nominal
// geometry, which apertures' spots overlap and so read as one group, and how
// far from a spot a site may lie and still be read.
#pragma once

#include <array>
#include <vector>

#include "digital_sun_sensor/sim/sensor_config.h"

namespace dss {

struct GeometryDesign {
  double height_um = 0.0;                           // detector surface to the mask's mid-plane
  std::vector<std::array<double, 2>> apertures_um;  // centres in the mask frame
  // Apertures whose spots overlap form one group, read as one spot: the
  // flux-weighted mean of its members' spots (exact for light that adds up).
  // Empty: every aperture its own group.
  std::vector<int> groups;
  std::vector<double> fluxes;       // relative flux per aperture (open area); empty: equal
  double glass_thickness_um = 0.0;  // cover glass on the detector (0: none)
  double glass_index = 1.0;
  double air_above_exit_um = 0.0;  // of the height, above the exit face: always in air (MaskGeometry)

  int groupCount() const;
};

// The nominal design of a sensor config (the height to the mask's
// mid-plane, where oblique light through a hole is centred): apertures closer than a spot
// diameter (sim/random_mask.h, spotDiameterUm) grouped, fluxes their areas.
GeometryDesign geometryDesignOf(const SensorConfig& config);

// Sites farther than this from every predicted spot are not read: half the
// least distance between apertures of different groups (a site is never
// nearer another group's spot), at most two spot diameters.
double geometricGateUm(const SensorConfig& config, const GeometryDesign& design);

}  // namespace dss
