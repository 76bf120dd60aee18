#include "digital_sun_sensor/sim/spot_cache.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <thread>
#include <vector>

#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/sim/geometry.h"

namespace dss {

SpotCache::SpotCache(OpticalPath path, double node_step_deg)
    : path_(std::move(path)), step_rad_(degToRad(node_step_deg)) {}

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

std::size_t SpotCache::nodesComputed() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return nodes_.size();
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
      future = it->second;
    } else {
      future = promise.get_future().share();
      nodes_.emplace(id, future);
      owner = true;
    }
  }
  if (owner) {
    // Computed outside the lock: other nodes proceed in parallel, and threads
    // that need this one wait on the future.
    try {
      const Eigen::Vector3d direction = path_.mode == OpticsMode::kFarField
                                            ? Eigen::Vector3d::UnitZ()
                                            : sunVectorFromAngles(ix * step_rad_, iy * step_rad_);
      promise.set_value(std::make_shared<const SpotMap>(computeSpotMap(aperture, direction, path_)));
    } catch (...) {
      promise.set_exception(std::current_exception());
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

SpotCache::Blend SpotCache::lookup(const ApertureGeometry& aperture, const Eigen::Vector3d& sun_mask) {
  const std::string key = aperture.key();
  Blend blend;
  if (path_.mode == OpticsMode::kFarField) {
    // The Fraunhofer shape does not depend on the incidence; only cos(theta) does.
    blend.maps[0] = node(aperture, key, 0, 0);
    blend.weights[0] = static_cast<float>(sun_mask.normalized().z());
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
    blend.maps[blend.count] = node(aperture, key, ix + (k & 1), iy + (k >> 1));
    blend.weights[blend.count] = static_cast<float>(w[k]);
    ++blend.count;
  }
  return blend;
}

SpotMap SpotCache::Blend::composed() const {
  SpotMap out;
  if (count == 0) return out;
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
  for (float v : out.values) out.peak = std::max(out.peak, v);
  return out;
}

}  // namespace dss
