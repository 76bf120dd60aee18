#include "digital_sun_sensor/model/physics_prior.h"

#include <algorithm>
#include <cmath>

#include "digital_sun_sensor/baseline/calibration_model.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/model/metadata.h"
#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/model/sscnn.h"
#include "digital_sun_sensor/sim/geometry.h"

namespace dss {

std::pair<double, double> centroidSlopes(const SensorConfig& config, double angle_scale_rad) {
  const MaskGeometry geometry = MaskGeometry::nominalOf(config);
  const double step_rad = degToRad(0.5);
  auto spot = [&](double alpha, double beta) { return geometry.spotPx(0, sunVectorFromAngles(alpha, beta)); };
  const auto xp = spot(step_rad, 0), xm = spot(-step_rad, 0), yp = spot(0, step_rad), ym = spot(0, -step_rad);
  if (!xp || !xm || !yp || !ym) return {0.0, 0.0};
  const double dx = ((*xp).x() - (*xm).x()) * 2.0 / config.detector.width_px;
  const double dy = ((*yp).y() - (*ym).y()) * 2.0 / config.detector.height_px;
  return {2 * step_rad / angle_scale_rad / dx, 2 * step_rad / angle_scale_rad / dy};
}

GeometricPrior geometricPrior(const SensorConfig& config, int size, double angle_scale_rad) {
  return geometricPrior(config, MaskGeometry::nominalOf(config), size, angle_scale_rad);
}

GeometricPrior geometricPrior(const SensorConfig& config, const MaskGeometry& unit, int size, double angle_scale_rad) {
  MaskGeometry centre = MaskGeometry::nominalOf(config);
  centre.height_um = unit.height_um;
  centre.offset_x_um = unit.offset_x_um;
  centre.offset_y_um = unit.offset_y_um;
  centre.rotation_rad = unit.rotation_rad;
  centre.tilt_x_rad = unit.tilt_x_rad;
  centre.tilt_y_rad = unit.tilt_y_rad;
  centre.air_above_exit_um = unit.air_above_exit_um;
  centre.apertures_um = {Eigen::Vector2d::Zero()};
  centre.aperture_diameters_um.resize(1);
  const double half_w = 0.5 * config.detector.width_px, half_h = 0.5 * config.detector.height_px;
  // The farther of the field's two edges per axis: a unit's offset moves the
  // lattice centre's spot toward one of them (a 3x wide_ma unit 40 um off
  // along +y, its extent taken at the +beta edge alone, declined 3-11 % of
  // its images near the -beta edge ambiguous_aperture: the true placement
  // lay outside the allowed shift).
  GeometricPrior prior;
  prior.extent_x = prior.extent_y = 0.0;
  for (const int sign : {1, -1}) {
    const double a = sign * 1.1 * config.fov.alpha_max_deg * kRadPerDeg;
    const double b = sign * 1.1 * config.fov.beta_max_deg * kRadPerDeg;
    const auto edge_x = centre.spotPx(0, sunVectorFromAngles(a, 0.0));
    const auto edge_y = centre.spotPx(0, sunVectorFromAngles(0.0, b));
    if (!edge_x || !edge_y) throw ModelError("geometric prior: no ray reaches the detector at the edge of the field");
    prior.extent_x = std::max(prior.extent_x, std::abs(edge_x->x()) / half_w);
    prior.extent_y = std::max(prior.extent_y, std::abs(edge_y->y()) / half_h);
  }
  prior.table = torch::zeros({2, size, size}, torch::kFloat);
  auto t = prior.table.accessor<float, 3>();
  const int mid = size / 2;
  auto node = [&](int k, double extent) { return extent * (2.0 * k / (size - 1) - 1.0); };
  // Centre outward, so that a node no ray reaches has its inner neighbour set.
  std::vector<int> order(static_cast<std::size_t>(size));
  for (int k = 0; k < size; ++k) order[static_cast<std::size_t>(k)] = k;
  std::sort(order.begin(), order.end(), [&](int a, int b) { return std::abs(a - mid) < std::abs(b - mid); });
  for (int row : order)
    for (int col : order) {
      const Eigen::Vector2d px(node(col, prior.extent_x) * half_w, node(row, prior.extent_y) * half_h);
      const SunSolution sun = solveSun(centre, {SpotObservation{0, px}});
      if (sun.ok) {
        t[0][row][col] = static_cast<float>(sun.alpha_rad / angle_scale_rad);
        t[1][row][col] = static_cast<float>(sun.beta_rad / angle_scale_rad);
      } else {
        const int inner_row = row + (row < mid) - (row > mid), inner_col = col + (col < mid) - (col > mid);
        t[0][row][col] = t[0][inner_row][inner_col];
        t[1][row][col] = t[1][inner_row][inner_col];
      }
    }
  return prior;
}

void setHeadGeometry(Model& model, const MaskGeometry& mask) {
  model.net->geometry()->setMaskGeometry(mask);
  if (model.meta.arch.geometric_prior_size <= 0) return;
  const GeometricPrior prior = geometricPrior(parseSensorConfig(model.meta.sensor_yaml, "the model's sensor"), mask,
                                              model.meta.arch.geometric_prior_size, model.meta.angle_scale_rad);
  model.net->initGeometricPrior(prior.table, prior.extent_x, prior.extent_y);
}

}  // namespace dss
