// Sun directions for datasets: uniform random over the field of view, uniform
// over its outer band (where the spot is cut by the detector edge: rare in a
// uniform draw, and where the largest errors arise), the published
// protocol's grid of spot centres on integer pixel offsets, or a spread lab
// plan (turntable points that cover the field evenly for any count).
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

#include "digital_sun_sensor/sim/sensor_config.h"

namespace dss {

enum class SamplingMode { kRandom, kEdge, kGrid, kSpread };

SamplingMode parseSamplingMode(const std::string& text);  // throws std::invalid_argument
std::string toString(SamplingMode mode);

class AttitudeSampler {
 public:
  // Grid: spot centres (single centred aperture) at integer pixel offsets
  // -W/2..W/2 from the detector centre (513 x 513 for the 512 px reference),
  // visited in a seeded random order; alpha = -atan(x p / h).
  // Edge: uniform over the part of the field within `edge_band_deg` of its
  // border in alpha or beta (required > 0 for kEdge, ignored otherwise).
  // Spread: the additive recurrence of the plastic number (Roberts' R2
  // sequence) over the field, shifted modulo the field by a seeded offset:
  // its first N points fill the field evenly for every N (a lab's first 25
  // turntable points leave no ninth of it empty), and each seed gives
  // another plan.
  AttitudeSampler(const SensorConfig& config, SamplingMode mode, std::uint64_t seed, double edge_band_deg = 0.0);

  // Sun vector (sensor frame) of dataset image `index`; deterministic.
  Eigen::Vector3d sunVector(std::uint64_t index) const;
  // Number of distinct grid points (0 for random sampling).
  std::uint64_t gridPoints() const { return order_.size(); }

 private:
  SamplingMode mode_;
  std::uint64_t seed_;
  double alpha_max_rad_, beta_max_rad_;
  double edge_band_rad_ = 0.0;
  double spread_shift_[2] = {0.0, 0.0};  // in units of the field's width
  double pitch_over_height_;
  int grid_half_x_ = 0, grid_half_y_ = 0;
  std::vector<std::uint32_t> order_;
};

}  // namespace dss
