// Renders a dataset of images + truth on several threads and hands them to a
// sink in index order, so that the output is identical for any thread count.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

#include "digital_sun_sensor/sim/renderer.h"
#include "digital_sun_sensor/sim/sampling.h"

namespace dss {

struct DatasetSpec {
  std::uint64_t count = 0;
  std::uint64_t seed = 0;
  SamplingMode sampling = SamplingMode::kRandom;
  double edge_band_deg = 0.2;  // kEdge: width of the field's outer band
  std::uint64_t offset = 0;    // first sample index (grid: position in the permutation)
  int instances = 1;           // sensors drawn from the config (as-built errors, debris, FPN)
  int threads = 2;
  RenderOptions render;
};

struct DatasetItem {
  std::uint64_t index = 0;
  int instance = 0;
  cv::Mat image;
  ImageTruth truth;
};

class DatasetGenerator {
 public:
  DatasetGenerator(const SensorConfig& config, const DatasetSpec& spec);

  // Calls `sink` for every item in index order. `progress(done, total)` after each block.
  void run(const std::function<void(const DatasetItem&)>& sink,
           const std::function<void(std::uint64_t, std::uint64_t)>& progress = {});

  // Continue at another sample index (same sensors, same warm caches).
  void setOffset(std::uint64_t offset) { spec_.offset = offset; }

  const Renderer& renderer(int instance) const { return *renderers_.at(instance); }

  // Seed of sensor instance k of a dataset seed.
  static std::uint64_t instanceSeed(std::uint64_t dataset_seed, int k);

 private:
  DatasetSpec spec_;
  AttitudeSampler sampler_;
  std::vector<std::unique_ptr<Renderer>> renderers_;
};

}  // namespace dss
