#include "digital_sun_sensor/sim/sampling.h"

#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/sim/geometry.h"

#include <cmath>
#include <numeric>
#include <stdexcept>

namespace dss {

SamplingMode parseSamplingMode(const std::string& text) {
  if (text == "random") return SamplingMode::kRandom;
  if (text == "grid") return SamplingMode::kGrid;
  throw std::invalid_argument("unknown sampling '" + text + "' (expected random or grid)");
}

std::string toString(SamplingMode mode) { return mode == SamplingMode::kRandom ? "random" : "grid"; }

AttitudeSampler::AttitudeSampler(const SensorConfig& config, SamplingMode mode, std::uint64_t seed)
    : mode_(mode),
      seed_(seed),
      alpha_max_rad_(config.fov.alpha_max_deg * M_PI / 180.0),
      beta_max_rad_(config.fov.beta_max_deg * M_PI / 180.0),
      pitch_over_height_(config.detector.pitch_um / (config.mask.height_mm * 1000.0)) {
  if (mode_ == SamplingMode::kGrid) {
    grid_half_x_ = config.detector.width_px / 2;
    grid_half_y_ = config.detector.height_px / 2;
    const std::uint64_t n = static_cast<std::uint64_t>(2 * grid_half_x_ + 1) * (2 * grid_half_y_ + 1);
    order_.resize(n);
    std::iota(order_.begin(), order_.end(), 0u);
    Rng rng(deriveSeed(seed, 0x6121D));
    for (std::uint64_t i = n - 1; i > 0; --i) std::swap(order_[i], order_[rng.below(i + 1)]);
  }
}

Eigen::Vector3d AttitudeSampler::sunVector(std::uint64_t index) const {
  if (mode_ == SamplingMode::kRandom) {
    Rng rng(deriveSeed(seed_, 0x5A3E000000ULL + index));
    const double alpha = rng.uniform(-alpha_max_rad_, alpha_max_rad_);
    const double beta = rng.uniform(-beta_max_rad_, beta_max_rad_);
    return sunVectorFromAngles(alpha, beta);
  }
  const std::uint32_t point = order_[(index) % order_.size()];
  const int width = 2 * grid_half_x_ + 1;
  const int x_px = static_cast<int>(point % width) - grid_half_x_;
  const int y_px = static_cast<int>(point / width) - grid_half_y_;
  // The spot moves opposite to the sun: a spot at +x means the sun at -alpha.
  return sunVectorFromAngles(-std::atan(x_px * pitch_over_height_), -std::atan(y_px * pitch_over_height_));
}

}  // namespace dss
