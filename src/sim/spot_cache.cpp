#include "digital_sun_sensor/sim/spot_cache.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <set>
#include <sstream>
#include <stdexcept>
#include <thread>
#include <vector>
#if defined(__GLIBC__)
#include <malloc.h>  // malloc_trim
#endif

#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/common/vector_clones.h"
#include "digital_sun_sensor/sim/geometry.h"

namespace dss {

namespace {

std::size_t defaultMemoryLimitBytes() {
  const long pages = sysconf(_SC_PHYS_PAGES), page_bytes = sysconf(_SC_PAGE_SIZE);
  if (pages <= 0 || page_bytes <= 0) return std::size_t{4} << 30;  // unknown: 4 GiB
  return static_cast<std::size_t>(0.4 * static_cast<double>(pages) * static_cast<double>(page_bytes));
}

std::atomic<std::size_t> memory_limit_bytes{defaultMemoryLimitBytes()};
std::atomic<std::size_t> memory_held_bytes{0};

std::size_t bytesOf(const SpotMap& map) { return sizeof(SpotMap) + map.values.size() * sizeof(float); }

// glibc keeps the dropped maps' memory in its heap (its mmap threshold rises
// past a map's size once the first is freed), where fragments of it stay
// unused: under a 9.4 GB cap, thesis_ca's units with debris grew to 15.9 GB
// in 20 minutes, and one malloc_trim brought them to 10.1 GB. So the memory
// is handed back after every so many bytes dropped.
constexpr std::size_t kTrimAfterDroppedBytes = std::size_t{256} << 20;
std::atomic<std::size_t> dropped_since_trim_bytes{0};

void handBackDroppedMemory() {
#if defined(__GLIBC__)
  malloc_trim(0);
#endif
}

// Every cache of the process, for the limit: where only the cache adding
// a map dropped its own, an idle cache (another renderer: a unit of
// another mask height, a design) kept all of its while the adder dropped
// maps its image still needed (10 as-built thesis_ma units in turn under
// 100 MB held 106 MB). Held while maps are dropped across caches, so that
// none is destroyed meanwhile.
std::mutex caches_mutex;
std::set<SpotCache*> caches;
std::atomic<std::uint64_t> use_clock{0};

}  // namespace

SpotCache::SpotCache(OpticalPath path, double node_step_deg)
    : path_(std::move(path)), step_rad_(degToRad(node_step_deg)) {
  std::lock_guard<std::mutex> lock(caches_mutex);
  caches.insert(this);
}

SpotCache::~SpotCache() {
  std::lock_guard<std::mutex> lock(caches_mutex);
  caches.erase(this);
  memory_held_bytes -= bytes_;
}

void SpotCache::setMemoryLimitBytes(std::size_t bytes) { memory_limit_bytes = bytes; }
std::size_t SpotCache::memoryLimitBytes() { return memory_limit_bytes; }
std::size_t SpotCache::memoryHeldBytes() { return memory_held_bytes; }

std::shared_ptr<SpotCache> SpotCache::shared(const OpticalPath& path, double node_step_deg) {
  // Every field of the path, exactly (hex floats), and the node step.
  std::ostringstream key;
  key << std::hexfloat << static_cast<int>(path.mode) << ' ' << path.air_gap_um << ' ' << path.glass_um << ' '
      << path.glass_index << ' ' << path.mask_thickness_um << ' ' << path.vignetting << ' ' << path.sun.enabled << ' '
      << path.sun.angular_diameter_deg << ' ' << path.sun.limb_darkening_u << ' ' << path.pitch_um << ' '
      << path.step_um << ' ' << path.grid_size << ' ' << node_step_deg;
  for (std::size_t i = 0; i < path.wavelengths_um.size(); ++i)
    key << ' ' << path.wavelengths_um[i] << ':' << (i < path.weights.size() ? path.weights[i] : 0.0);
  static std::mutex registry_mutex;
  static std::map<std::string, std::weak_ptr<SpotCache>> registry;
  std::lock_guard<std::mutex> lock(registry_mutex);
  std::weak_ptr<SpotCache>& slot = registry[key.str()];
  std::shared_ptr<SpotCache> cache = slot.lock();
  if (!cache) {
    cache = std::make_shared<SpotCache>(path, node_step_deg);
    slot = cache;
  }
  return cache;
}

std::size_t SpotCache::nodesHeld() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return nodes_.size();
}

std::size_t SpotCache::bytesHeld() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return bytes_;
}

std::size_t SpotCache::nodesDropped() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return dropped_;
}

std::list<std::string>::iterator SpotCache::droppable(const std::string& keep) {
  auto id = used_.begin();
  while (id != used_.end() && (nodes_.at(*id).bytes == 0 || *id == keep)) ++id;
  return id;
}

std::size_t SpotCache::dropOverLimit(const SpotCache* adder, const std::string& keep) {
  const std::size_t limit = memory_limit_bytes;
  std::size_t dropped_bytes = 0;
  if (limit == 0 || memory_held_bytes <= limit) return 0;  // every map added below the limit: no lock taken
  std::lock_guard<std::mutex> registry(caches_mutex);
  while (memory_held_bytes > limit) {
    // The cache whose droppable map was used longest ago (one cache's
    // mutex at a time: never two, so no order between them to keep).
    SpotCache* oldest = nullptr;
    std::uint64_t oldest_use = 0;
    for (SpotCache* cache : caches) {
      std::lock_guard<std::mutex> lock(cache->mutex_);
      const auto id = cache->droppable(cache == adder ? keep : std::string());
      if (id == cache->used_.end()) continue;
      const std::uint64_t use = cache->nodes_.at(*id).last_use;
      if (!oldest || use < oldest_use) oldest = cache, oldest_use = use;
    }
    if (!oldest) break;
    std::lock_guard<std::mutex> lock(oldest->mutex_);
    const auto id = oldest->droppable(oldest == adder ? keep : std::string());
    if (id == oldest->used_.end()) continue;  // used meanwhile: look again
    const auto entry = oldest->nodes_.find(*id);
    oldest->bytes_ -= entry->second.bytes;
    memory_held_bytes -= entry->second.bytes;
    dropped_bytes += entry->second.bytes;
    oldest->nodes_.erase(entry);
    oldest->used_.erase(id);
    ++oldest->dropped_;
  }
  return dropped_bytes;
}

std::shared_ptr<const SpotMap> SpotCache::node(const ApertureGeometry& aperture, const std::string& key, int ix,
                                               int iy) {
  const std::string id = key + '@' + std::to_string(ix) + ',' + std::to_string(iy);
  std::promise<std::shared_ptr<const SpotMap>> promise;
  std::shared_future<std::shared_ptr<const SpotMap>> future;
  bool owner = false;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    auto it = nodes_.find(id);
    if (it != nodes_.end()) {
      future = it->second.map;
      used_.splice(used_.end(), used_, it->second.used);
      it->second.last_use = ++use_clock;
    } else {
      future = promise.get_future().share();
      used_.push_back(id);
      nodes_.emplace(id, Entry{future, 0, std::prev(used_.end()), ++use_clock});
      owner = true;
    }
  }
  if (owner) {
    // Computed outside the lock: other nodes proceed in parallel, and threads
    // that need this one wait on the future.
    std::size_t bytes = 0;
    try {
      const Eigen::Vector3d direction = path_.mode == OpticsMode::kFarField
                                            ? Eigen::Vector3d::UnitZ()
                                            : sunVectorFromAngles(ix * step_rad_, iy * step_rad_);
      auto map = std::make_shared<const SpotMap>(computeSpotMap(aperture, direction, path_));
      bytes = bytesOf(*map);
      promise.set_value(std::move(map));
    } catch (...) {
      promise.set_exception(std::current_exception());
    }
    if (bytes > 0) {
      {
        std::lock_guard<std::mutex> lock(mutex_);
        nodes_.at(id).bytes = bytes;  // never dropped while computing: still held
        bytes_ += bytes;
        memory_held_bytes += bytes;
      }
      const std::size_t dropped_bytes = dropOverLimit(this, id);
      if (dropped_bytes > 0 && (dropped_since_trim_bytes += dropped_bytes) >= kTrimAfterDroppedBytes) {
        dropped_since_trim_bytes = 0;
        handBackDroppedMemory();
      }
    }
  }
  return future.get();
}

void SpotCache::warmUp(const ApertureGeometry& aperture, double alpha_max_rad, double beta_max_rad, int threads,
                       const std::function<void(std::size_t, std::size_t)>& progress) {
  const std::string key = aperture.key();
  std::vector<std::pair<int, int>> todo;
  if (path_.mode == OpticsMode::kFarField) {
    todo.emplace_back(0, 0);
  } else {
    const int nx = static_cast<int>(std::ceil(alpha_max_rad / step_rad_));
    const int ny = static_cast<int>(std::ceil(beta_max_rad / step_rad_));
    for (int iy = -ny; iy <= ny; ++iy) {
      for (int ix = -nx; ix <= nx; ++ix) todo.emplace_back(ix, iy);
    }
  }
  std::atomic<std::size_t> next{0}, done{0};
  std::mutex progress_mutex;
  auto work = [&] {
    for (std::size_t i; (i = next++) < todo.size();) {
      node(aperture, key, todo[i].first, todo[i].second);
      const std::size_t d = ++done;
      if (progress) {
        std::lock_guard<std::mutex> lock(progress_mutex);
        progress(d, todo.size());
      }
    }
  };
  std::vector<std::thread> pool;
  for (int t = 1; t < threads; ++t) pool.emplace_back(work);
  work();
  for (auto& t : pool) t.join();
}

SpotCache::NodeBlend SpotCache::nodesOf(const Eigen::Vector3d& sun_mask) const {
  NodeBlend blend;
  if (path_.mode == OpticsMode::kFarField) {
    // The Fraunhofer shape does not depend on the incidence; only cos(theta) does.
    blend.nodes[0] = {0, 0, static_cast<float>(sun_mask.normalized().z())};
    blend.count = 1;
    return blend;
  }
  const SunAnglesRad a = anglesFromSunVector(sun_mask);
  const double gx = a.alpha / step_rad_, gy = a.beta / step_rad_;
  const int ix = static_cast<int>(std::floor(gx)), iy = static_cast<int>(std::floor(gy));
  const double fx = gx - ix, fy = gy - iy;
  const double w[4] = {(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy};
  for (int k = 0; k < 4; ++k) {
    if (w[k] < 1e-9) continue;
    blend.nodes[blend.count++] = {ix + (k & 1), iy + (k >> 1), static_cast<float>(w[k])};
  }
  return blend;
}

SpotCache::Blend SpotCache::lookup(const ApertureGeometry& aperture, const Eigen::Vector3d& sun_mask) {
  const std::string key = aperture.key();
  const NodeBlend nodes = nodesOf(sun_mask);
  Blend blend;
  for (int k = 0; k < nodes.count; ++k) {
    blend.maps[k] = node(aperture, key, nodes.nodes[k].ix, nodes.nodes[k].iy);
    blend.weights[k] = nodes.nodes[k].weight;
  }
  blend.count = nodes.count;
  return blend;
}

namespace {

// to[i] = sum over k < N of weights[k] from[k][i], summed in order of k
// (N a constant: the loop over i vectorises).
template <int N>
void weightedSum(const std::array<const float*, 4>& from, const std::array<float, 4>& weights, std::vector<float>& to) {
  float* out = to.data();
  for (std::size_t i = 0, n = to.size(); i < n; ++i) {
    float v = weights[0] * from[0][i];
    for (int k = 1; k < N; ++k) v += weights[k] * from[k][i];
    out[i] = v;
  }
}

}  // namespace

SpotMap SpotCache::Blend::composed() const {
  SpotMap out;
  composeInto(out);
  return out;
}

DSS_VECTOR_CLONES
void SpotCache::Blend::composeInto(SpotMap& out) const {
  std::vector<float> storage = std::move(out.values);
  out = SpotMap{};
  out.values = std::move(storage);
  if (count == 0) {
    out.values.clear();
    return;
  }
  const double step = maps[0]->step_um;
  double u_lo = maps[0]->u0_um, v_lo = maps[0]->v0_um;
  for (int k = 1; k < count; ++k) u_lo = std::min(u_lo, maps[k]->u0_um), v_lo = std::min(v_lo, maps[k]->v0_um);
  auto cellOf = [step](double from, double to) { return static_cast<int>(std::lround((to - from) / step)); };
  for (int k = 0; k < count; ++k) {
    const SpotMap& m = *maps[k];
    if (m.step_um != step) throw std::logic_error("spot cache: blended maps on different grid steps");
    out.cols = std::max(out.cols, cellOf(u_lo, m.u0_um) + m.cols);
    out.rows = std::max(out.rows, cellOf(v_lo, m.v0_um) + m.rows);
  }
  out.step_um = step;
  out.u0_um = u_lo;
  out.v0_um = v_lo;
  bool one_lattice = true;  // every map on the same samples (thesis_ca's: the whole FFT grid, uncropped)
  for (int k = 0; k < count; ++k)
    one_lattice = one_lattice && maps[k]->u0_um == u_lo && maps[k]->v0_um == v_lo && maps[k]->cols == out.cols &&
                  maps[k]->rows == out.rows;
  if (one_lattice) {
    // One pass, each sample summed in the same order as below (0 + w0 m0 is
    // w0 m0 exactly): below, the output is read and written once per map,
    // three times the memory traffic. Every sample is written: the storage
    // kept from `out` is not zeroed first.
    out.values.resize(static_cast<std::size_t>(out.rows) * out.cols);
    std::array<const float*, 4> from{};
    for (int k = 0; k < count; ++k) from[k] = maps[k]->values.data();
    switch (count) {
      case 1:
        weightedSum<1>(from, weights, out.values);
        break;
      case 2:
        weightedSum<2>(from, weights, out.values);
        break;
      case 3:
        weightedSum<3>(from, weights, out.values);
        break;
      default:
        weightedSum<4>(from, weights, out.values);
        break;
    }
    for (int k = 0; k < count; ++k) out.total_power_um2 += weights[k] * maps[k]->total_power_um2;
    return;
  }
  out.values.assign(static_cast<std::size_t>(out.rows) * out.cols, 0.0f);
  for (int k = 0; k < count; ++k) {
    const SpotMap& m = *maps[k];
    const int dc = cellOf(u_lo, m.u0_um), dr = cellOf(v_lo, m.v0_um);
    for (int r = 0; r < m.rows; ++r) {
      const float* in = &m.values[static_cast<std::size_t>(r) * m.cols];
      float* row = &out.values[static_cast<std::size_t>(r + dr) * out.cols + dc];
      for (int c = 0; c < m.cols; ++c) row[c] += weights[k] * in[c];
    }
    out.total_power_um2 += weights[k] * m.total_power_um2;
  }
}

}  // namespace dss
