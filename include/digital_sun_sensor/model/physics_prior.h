// Physics priors of a model, from the sensor's nominal geometry (or a calibrated unit's): the
// slope from the spot centroid to the angles, and for wide fields a table of
// the angles over the spot position. Training then learns corrections.
#pragma once

#include <torch/types.h>

#include <utility>

#include "digital_sun_sensor/sim/sensor_config.h"

namespace dss {

struct MaskGeometry;
struct Model;

// d(angle / angle_scale) / d(normalized centroid) per axis of the nominal
// sensor (pinhole + refraction), by central differences at normal incidence;
// (0, 0) when no ray reaches the detector there.
std::pair<double, double> centroidSlopes(const SensorConfig& config, double angle_scale_rad);

// The nominal geometry's angles (normalized) over a grid of lattice-centre
// spot positions spanning the field of view plus 10 %, by inverting the ray
// trace (baseline solveSun) at each node; nodes no ray reaches copy their
// neighbour toward the centre.
struct GeometricPrior {
  torch::Tensor table;  // [2, size, size]
  double extent_x = 1.0, extent_y = 1.0;
};
GeometricPrior geometricPrior(const SensorConfig& config, int size, double angle_scale_rad);
// The same through a built unit's mask height, offset, rotation and tilt
// (`unit`: the geometric head's fitted geometry, any pitch): the coarse
// estimate and the lattice placements the field of view allows follow the
// unit (a 3x wide_ma unit's spots at 60 deg lie past the design's extent).
GeometricPrior geometricPrior(const SensorConfig& config, const MaskGeometry& unit, int size, double angle_scale_rad);

// Sets a geometric head's mask geometry and, where the model has a geometric
// prior, the prior through it, so that the coarse estimate and the lattice
// placements follow the geometry (calibrate-unit's fit; calibrate-height's
// moved design, whose spots at the field's edge lie past the design's
// extent). Throws ModelError on a sensor config the model does not parse.
void setHeadGeometry(Model& model, const MaskGeometry& mask);

}  // namespace dss
