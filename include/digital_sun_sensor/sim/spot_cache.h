// Spot shapes cached on a grid of incidence angles and blended bilinearly:
// across a thesis sensor's +-4.5 deg field the shape changes only through
// vignetting, obliquity and foreshortening, all smooth in angle, so a few
// dozen diffraction computations serve millions of images. Thread-safe;
// nodes are computed lazily, once, by the first thread that needs them.
// The maps of every cache together hold at most a memory limit: a unit
// whose apertures differ (as-built diameters, debris) needs a map set per
// aperture, which for thesis_ca's 117 would grow past any machine's memory.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <future>
#include <list>
#include <map>
#include <memory>
#include <mutex>
#include <string>

#include "digital_sun_sensor/sim/optics.h"

namespace dss {

class SpotCache {
 public:
  explicit SpotCache(OpticalPath path, double node_step_deg);
  ~SpotCache();
  SpotCache(const SpotCache&) = delete;
  SpotCache& operator=(const SpotCache&) = delete;

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
    // The same into `out`, whose sample storage it reuses (a render composes
    // a blend per image: a fresh map's zeroed megabyte each time).
    void composeInto(SpotMap& out) const;
  };

  // The nodes an incidence direction `sun_mask` (mask frame) blends, with
  // bilinear weights in (alpha, beta) of the mask frame; in the far field
  // node (0, 0) alone, weighted cos(theta).
  struct NodeWeight {
    int ix = 0, iy = 0;
    float weight = 0.0f;
  };
  struct NodeBlend {
    std::array<NodeWeight, 4> nodes;
    int count = 0;
  };
  NodeBlend nodesOf(const Eigen::Vector3d& sun_mask) const;

  // Maps around the incidence direction `sun_mask` (unit, mask frame), with
  // the weights of nodesOf.
  Blend lookup(const ApertureGeometry& aperture, const Eigen::Vector3d& sun_mask);

  // Computes every node an incidence within +-alpha_max, +-beta_max [rad]
  // can touch, on `threads` threads; `progress(done, total)` after each node.
  void warmUp(const ApertureGeometry& aperture, double alpha_max_rad, double beta_max_rad, int threads,
              const std::function<void(std::size_t, std::size_t)>& progress = {});

  const OpticalPath& path() const { return path_; }
  std::size_t nodesHeld() const;
  std::size_t bytesHeld() const;
  std::size_t nodesDropped() const;  // for the memory limit, since this cache was made

  // The memory the maps of every cache in the process may hold together
  // [bytes]. Past it, the least recently used maps of any cache are dropped
  // (a map in use stays alive with its user); a dropped node is computed
  // again when needed, to the same values, at the cost of its diffraction.
  // Default: 40 % of the machine's memory; 0: no limit.
  static void setMemoryLimitBytes(std::size_t bytes);
  static std::size_t memoryLimitBytes();
  static std::size_t memoryHeldBytes();  // by every cache together

 private:
  struct Entry {
    std::shared_future<std::shared_ptr<const SpotMap>> map;
    std::size_t bytes = 0;                  // 0 while computing (never dropped then)
    std::list<std::string>::iterator used;  // its place in used_
    std::uint64_t last_use = 0;             // on the process-wide use clock
  };
  std::shared_ptr<const SpotMap> node(const ApertureGeometry& aperture, const std::string& key, int ix, int iy);
  // This cache's least recently used map that may be dropped (held, not
  // `keep`): its id in used_, or used_.end(). Under mutex_.
  std::list<std::string>::iterator droppable(const std::string& keep);
  // Drops the least recently used maps of every cache in the process (not
  // `keep` of `adder`) while they hold more than the limit; returns their
  // bytes. Under no cache's mutex.
  static std::size_t dropOverLimit(const SpotCache* adder, const std::string& keep);

  OpticalPath path_;
  double step_rad_;
  mutable std::mutex mutex_;
  std::map<std::string, Entry> nodes_;
  std::list<std::string> used_;  // node ids, least recently used first
  std::size_t bytes_ = 0, dropped_ = 0;
};

}  // namespace dss
