// The credibility report (dss report): generates its own test data, evaluates
// the SSCNN and the centroid baseline side by side and writes DIR/index.html
// (self-contained apart from its PNG plots), DIR/*.png and DIR/summary.json.
// Sections: accuracy over the field of view (error maps, histograms, error
// against truth), honesty of the predicted uncertainty (coverage, reliability),
// robustness to each noise and anomaly term swept from none to severe, how
// often inputs are flagged invalid (false alarms on nominal data, flags under
// severe conditions), the published results, provenance. Torch-free: the
// estimators come in through the SunEstimator interface.
#pragma once

#include <cstdint>
#include <functional>
#include <string>

#include "digital_sun_sensor/common/sun_estimate.h"

namespace dss {

struct ReportOptions {
  std::string out_dir;
  std::uint64_t seed = 1;
  int test_images = 2000;  // nominal set: maps, histograms, coverage, false alarms
  int sweep_images = 100;  // per robustness level
  int sweep_sensors = 4;   // sensors drawn per level (per-sensor hot pixels, debris)
  int map_bins = 12;       // heat-map cells per axis
  int threads = 2;         // render threads
  // Provenance, shown as given.
  std::string command, sensor_path, sscnn_description, baseline_description, model_metadata_yaml;

  void validate() const;  // throws std::invalid_argument naming the field
};

// `progress(stage, done, total)` after each block of work. Returns the summary
// JSON (also written to DIR/summary.json). `baseline` may be null.
std::string writeReport(const SensorConfig& sensor, SunEstimator& sscnn, SunEstimator* baseline,
                        const ReportOptions& options,
                        const std::function<void(const std::string&, std::size_t, std::size_t)>& progress = {});

}  // namespace dss
