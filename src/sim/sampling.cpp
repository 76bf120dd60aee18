#include "digital_sun_sensor/sim/sampling.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <stdexcept>

#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/sim/geometry.h"

namespace dss {
namespace {

// R2's steps: 1 / g and 1 / g^2 for the plastic number g (g^3 = g + 1), the
// two-dimensional golden ratio; its points stay evenly spread for every count.
constexpr double kPlasticNumber = 1.32471795724474602596;
constexpr double kSpreadStep[2] = {1.0 / kPlasticNumber, 1.0 / (kPlasticNumber * kPlasticNumber)};

}  // namespace

SamplingMode parseSamplingMode(const std::string& text) {
  if (text == "random") return SamplingMode::kRandom;
  if (text == "edge") return SamplingMode::kEdge;
  if (text == "grid") return SamplingMode::kGrid;
  if (text == "spread") return SamplingMode::kSpread;
  throw std::invalid_argument("unknown sampling '" + text + "' (expected random, edge, grid or spread)");
}

std::string toString(SamplingMode mode) {
  switch (mode) {
    case SamplingMode::kRandom:
      return "random";
    case SamplingMode::kEdge:
      return "edge";
    case SamplingMode::kSpread:
      return "spread";
    case SamplingMode::kGrid:
      break;
  }
  return "grid";
}

AttitudeSampler::AttitudeSampler(const SensorConfig& config, SamplingMode mode, std::uint64_t seed,
                                 double edge_band_deg)
    : mode_(mode),
      seed_(seed),
      alpha_max_rad_(degToRad(config.fov.alpha_max_deg)),
      beta_max_rad_(degToRad(config.fov.beta_max_deg)),
      pitch_over_height_(config.detector.pitch_um / (config.mask.height_mm * 1000.0)) {
  if (mode_ == SamplingMode::kEdge) {
    if (!(edge_band_deg > 0.0) || edge_band_deg > std::min(config.fov.alpha_max_deg, config.fov.beta_max_deg))
      throw std::invalid_argument("edge sampling: the band (" + std::to_string(edge_band_deg) +
                                  " deg) must be > 0 and at most the half field of view");
    edge_band_rad_ = degToRad(edge_band_deg);
  }
  if (mode_ == SamplingMode::kSpread) {
    Rng rng(deriveSeed(seed, 0x5E7EADULL));
    spread_shift_[0] = rng.uniform(0.0, 1.0);
    spread_shift_[1] = rng.uniform(0.0, 1.0);
  }
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
  if (mode_ == SamplingMode::kEdge) {
    // Uniform over the band by rejection from the whole field: a few draws
    // for bands of a few per cent, and the same direction for an index
    // whatever the thread that asks.
    Rng rng(deriveSeed(seed_, 0xED6E000000ULL + index));
    for (;;) {
      const double alpha = rng.uniform(-alpha_max_rad_, alpha_max_rad_);
      const double beta = rng.uniform(-beta_max_rad_, beta_max_rad_);
      if (std::abs(alpha) >= alpha_max_rad_ - edge_band_rad_ || std::abs(beta) >= beta_max_rad_ - edge_band_rad_)
        return sunVectorFromAngles(alpha, beta);
    }
  }
  if (mode_ == SamplingMode::kSpread) {
    // Point 0 would be the shift itself: start at 1. (The fraction of
    // index * step keeps ~1e-10 up to index 1e6.)
    auto at = [&](int axis) {
      const double x = static_cast<double>(index + 1) * kSpreadStep[axis] + spread_shift_[axis];
      return x - std::floor(x);
    };
    const double u = at(0), v = at(1);
    return sunVectorFromAngles((2.0 * u - 1.0) * alpha_max_rad_, (2.0 * v - 1.0) * beta_max_rad_);
  }
  const std::uint32_t point = order_[(index) % order_.size()];
  const int width = 2 * grid_half_x_ + 1;
  const int x_px = static_cast<int>(point % width) - grid_half_x_;
  const int y_px = static_cast<int>(point / width) - grid_half_y_;
  // The spot moves opposite to the sun: a spot at +x means the sun at -alpha.
  return sunVectorFromAngles(-std::atan(x_px * pitch_over_height_), -std::atan(y_px * pitch_over_height_));
}

}  // namespace dss
