// The credibility report (dss report): generates its own test data, evaluates
// the SSCNN and the centroid baseline side by side and writes DIR/index.html
// (self-contained apart from its PNG plots), DIR/*.png and DIR/summary.json.
// Sections: accuracy over the field of view (error maps, histograms, error
// against truth), honesty of the predicted uncertainty (coverage, reliability),
// robustness to each noise and anomaly term swept from none to severe, how
// often inputs are flagged invalid (false alarms on nominal data, flags under
// severe conditions), the published results beside a model trained on the
// published protocol, provenance. Torch-free: the estimators come in through
// the SunEstimator interface.
#pragma once

#include <cstdint>
#include <functional>
#include <string>

#include "digital_sun_sensor/common/sun_estimate.h"
#include "digital_sun_sensor/sim/sensor_config.h"

namespace dss {

struct ReportOptions {
  std::string out_dir;
  std::uint64_t seed = 1;
  int test_images = 2000;  // nominal set: maps, histograms, coverage, false alarms
  int sweep_images = 100;  // per robustness level
  int sweep_sensors = 4;   // sensors drawn per level (per-sensor hot pixels, debris)
  int map_bins = 12;       // heat-map cells per axis
  int threads = 2;         // render threads
  // Published protocol: test images at grid positions of this seed from this
  // offset on (scripts/train_published.sh trains on positions 0..29999 of
  // seed 531 and tests from 30000).
  int published_images = 1000;
  std::uint64_t published_grid_seed = 531, published_grid_offset = 30000;
  // Provenance, shown as given.
  std::string command, sensor_path, sscnn_description, baseline_description, model_metadata_yaml;
  std::string published_sscnn_description, published_baseline_description;

  void validate() const;  // throws std::invalid_argument naming the field
};

// A model trained on the published protocol (docs/design.md, "Reference sensor": far-field
// optics, spot centres on the pixel grid) and a baseline calibrated on it,
// evaluated on the protocol's images beside the published SSCNN's figures.
struct PublishedProtocolRun {
  SensorConfig sensor;  // the protocol's sensor (as embedded in the model)
  SunEstimator* sscnn = nullptr;
  SunEstimator* baseline = nullptr;  // may be null
};

// `progress(stage, done, total)` after each block of work. Returns the summary
// JSON (also written to DIR/summary.json). `baseline` and `published` may be
// null (without `published` the report shows the published figures alone).
std::string writeReport(const SensorConfig& sensor, SunEstimator& sscnn, SunEstimator* baseline,
                        const ReportOptions& options,
                        const std::function<void(const std::string&, std::size_t, std::size_t)>& progress = {},
                        const PublishedProtocolRun* published = nullptr);

}  // namespace dss
