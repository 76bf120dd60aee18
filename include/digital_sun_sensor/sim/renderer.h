// Sun vector -> digital sun sensor image, with ground truth. Pipeline:
// optics (cached diffraction spots per aperture) -> radiometry and exposure ->
// anomalies (stray light, ghosts) -> detector (EMVA 1288: PRNU, dark current
// and DSNU, hot pixels, shot and read noise, full well, gain, black level,
// ADC) -> on-chip thresholding. Deterministic for a given image seed;
// thread-safe (one Renderer serves many threads).
#pragma once

#include <Eigen/Core>
#include <functional>
#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/sim/sensor_instance.h"

namespace dss {

class SpotCache;
class ReadoutTable;

struct SpotTruth {
  int aperture_index = 0;
  double x_px = 0.0;  // from the detector centre, +x along columns
  double y_px = 0.0;  // from the detector centre, +y along rows
  bool on_detector = false;
  float relative_flux = 0.0f;  // power vs an unvignetted aperture at normal incidence
};

struct ImageTruth {
  double alpha_rad = 0.0;
  double beta_rad = 0.0;
  Eigen::Vector3d sun = Eigen::Vector3d::UnitZ();
  int subfov_class = -1;
  std::vector<SpotTruth> spots;
  double exposure_s = 0.0;
  bool stray_light = false;
  bool ghost = false;
};

struct RenderOptions {
  bool noise = true;      // detector noise and fixed patterns (else the mean image, quantised)
  bool anomalies = true;  // per-image anomalies of the config (stray light, ghosts)
  bool threshold = true;  // on-chip thresholding if the config enables it
  // CV_8U, the detector's size: light only the pixels it marks (the rest
  // read as unlit), for callers that need a few of them (the pattern
  // estimator's design images). The exposure then follows the brightest
  // marked pixel, which must be the image's brightest for the same image.
  const cv::Mat* only = nullptr;
};

class Renderer {
 public:
  explicit Renderer(SensorInstance instance);
  ~Renderer();

  // Mean signal photoelectrons per pixel (CV_32F) for a sun vector in the
  // sensor frame, after exposure control; fills `truth`. Per-image anomalies
  // are drawn from `anomaly_rng` when given; `only` as RenderOptions::only.
  // With `shape_sun`, the spots lie where `sun` puts them but are shaped as
  // for that direction (baseline/design_canvases.h).
  cv::Mat expectedElectrons(const Eigen::Vector3d& sun, ImageTruth* truth, Rng* anomaly_rng = nullptr,
                            const cv::Mat* only = nullptr, const Eigen::Vector3d* shape_sun = nullptr) const;

  // Detector: electrons (CV_32F) -> digital numbers (CV_8U for <= 8 bits, else CV_16U).
  cv::Mat detect(const cv::Mat& signal_e, double exposure_s, Rng& rng, const RenderOptions& options = {}) const;

  // The whole chain; deterministic in (instance, sun, image_seed).
  cv::Mat render(const Eigen::Vector3d& sun, std::uint64_t image_seed, ImageTruth* truth,
                 const RenderOptions& options = {}) const;

  // Fills the diffraction cache for the whole field of view (plus the as-built
  // mask tilt margin) on `threads` threads, instead of lazily during rendering.
  void warmUp(int threads, const std::function<void(std::size_t, std::size_t)>& progress = {}) const;

  const SensorInstance& instance() const { return instance_; }
  const SensorConfig& config() const { return instance_.config; }
  SpotCache& spotCache() const { return *cache_; }

  double darkElectronsPerSecond() const;

 private:
  SensorInstance instance_;
  std::shared_ptr<SpotCache> cache_;  // SpotCache::shared: one per optical path in the process
  std::unique_ptr<ReadoutTable> readout_;
  double electron_rate_ = 0.0;
  std::vector<std::string> shape_keys_;  // per aperture: its shape's key (formatted once, not per image)
};

// Sub-FOV class of a truth (quadrant, or the aperture whose spot is nearest the
// detector centre).
int subFovClass(const SensorConfig& config, const ImageTruth& truth);

}  // namespace dss
