// Spot shapes cached on a grid of incidence angles and blended bilinearly:
// across a thesis sensor's +-4.5 deg field the shape changes only through
// vignetting, obliquity and foreshortening, all smooth in angle, so a few
// dozen diffraction computations serve millions of images. Thread-safe;
// nodes are computed lazily, once, by the first thread that needs them.
#pragma once

#include <array>
#include <functional>
#include <future>
#include <map>
#include <memory>
#include <mutex>
#include <string>

#include "digital_sun_sensor/sim/optics.h"

namespace dss {

class SpotCache {
 public:
  explicit SpotCache(OpticalPath path, double node_step_deg);

  // One cache per optical path and node step in the whole process, shared by
  // every renderer that needs it (sensors that differ only in detector,
  // exposure or anomalies reuse each other's diffraction work); released
  // with the last renderer holding it.
  static std::shared_ptr<SpotCache> shared(const OpticalPath& path, double node_step_deg);

  struct Blend {
    std::array<std::shared_ptr<const SpotMap>, 4> maps;
    std::array<float, 4> weights{};
    int count = 0;

    // The weighted sum of the maps as one map on their common sample
    // lattice (every node's crop starts on a multiple of the grid step):
    // sampling it equals the weighted sum of their samples, bilinear
    // interpolation being linear, for a quarter of the lookups when one
    // blend serves many apertures of the same shape.
    SpotMap composed() const;
  };

  // Maps around the incidence direction `sun_mask` (unit, mask frame), with
  // bilinear weights in (alpha, beta) of the mask frame.
  Blend lookup(const ApertureGeometry& aperture, const Eigen::Vector3d& sun_mask);

  // Computes every node an incidence within +-alpha_max, +-beta_max [rad]
  // can touch, on `threads` threads; `progress(done, total)` after each node.
  void warmUp(const ApertureGeometry& aperture, double alpha_max_rad, double beta_max_rad, int threads,
              const std::function<void(std::size_t, std::size_t)>& progress = {});

  const OpticalPath& path() const { return path_; }
  std::size_t nodesComputed() const;

 private:
  std::shared_ptr<const SpotMap> node(const ApertureGeometry& aperture, const std::string& key, int ix, int iy);

  OpticalPath path_;
  double step_rad_;
  mutable std::mutex mutex_;
  std::map<std::string, std::shared_future<std::shared_ptr<const SpotMap>>> nodes_;
};

}  // namespace dss
