// Whether a unit's estimates still agree with an independent reference sun
// direction (in flight: a star tracker and an ephemeris) within their own
// sigma. A mask that drifted as a whole (height, offset) moves every spot
// alike, which one image cannot tell from a change of angle: the spots stay
// consistent with each other, so model_mismatch stays quiet, and the
// estimates keep their calibrated sigma while off by tenths of a degree or
// more. Against references that shows; until a refit of the geometry brings
// the estimates back, each one's sigma is widened by the residual the
// references show. Torch-free header.
#pragma once

#include <array>
#include <cstddef>
#include <deque>

#include "digital_sun_sensor/common/sun_estimate.h"

namespace dss {

struct ConsistencyOptions {
  std::size_t window = 50;             // recent pairs judged
  std::size_t min_pairs = 10;          // pairs before any judgement
  double reference_sigma_deg = 0.001;  // the reference's own error per axis (attitude and ephemeris)
  double max_normalized = 3.0;         // robust RMS of residual / expected sigma beyond which sigma is widened

  // Throws std::invalid_argument naming the first bad value.
  void validate() const;
};

class ReferenceConsistency {
 public:
  explicit ReferenceConsistency(ConsistencyOptions options = {});

  // One estimate (its own sigma, before any widening) and the reference for
  // the same image [rad]. Estimates that are not finite are ignored.
  void add(const SunEstimate& estimate, const std::array<double, 2>& reference_rad);
  // The geometry changed (a refit): the earlier residuals no longer describe it.
  void reset();

  std::size_t pairs() const { return residuals_.size(); }
  // Per axis, the robust RMS (from the median square) of residual over its
  // expected sigma in the window; 0 before min_pairs.
  const std::array<double, 2>& normalizedRms() const { return normalized_; }
  // Per axis, the sigma [rad] added in quadrature to every estimate: the
  // window's robust residual RMS on an axis whose normalized RMS exceeds
  // max_normalized, else 0. Robust (from the median square, as for normal
  // residuals): gross references do not move it, and a residual that is the
  // same in every pair reads 1.48 times itself.
  const std::array<double, 2>& extraSigmaRad() const { return extra_rad_; }
  bool inconsistent() const { return extra_rad_[0] > 0.0 || extra_rad_[1] > 0.0; }
  // Widens a valid estimate's covariance (and the part its images share) by extraSigmaRad.
  void widen(SunEstimate& estimate) const;

 private:
  struct Pair {
    std::array<double, 2> residual_rad, expected_rad;
  };
  void update();

  ConsistencyOptions options_;
  std::deque<Pair> residuals_;
  std::array<double, 2> normalized_{}, extra_rad_{};
};

}  // namespace dss
