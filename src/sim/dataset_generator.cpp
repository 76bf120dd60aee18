#include "digital_sun_sensor/sim/dataset_generator.h"

#include <algorithm>
#include <atomic>
#include <exception>
#include <stdexcept>
#include <thread>

namespace dss {

std::uint64_t DatasetGenerator::instanceSeed(std::uint64_t dataset_seed, int k) {
  return deriveSeed(dataset_seed, 0x1257A0CEULL + static_cast<std::uint64_t>(k));
}

DatasetGenerator::DatasetGenerator(const SensorConfig& config, const DatasetSpec& spec)
    : spec_(spec), sampler_(config, spec.sampling, spec.seed, spec.edge_band_deg) {
  if (spec_.instances < 1) throw std::invalid_argument("instances must be >= 1");
  if (spec_.threads < 1) spec_.threads = 1;
  for (int k = 0; k < spec_.instances; ++k) {
    renderers_.push_back(std::make_unique<Renderer>(SensorInstance::draw(config, instanceSeed(spec.seed, k))));
  }
}

void DatasetGenerator::run(const std::function<void(const DatasetItem&)>& sink,
                           const std::function<void(std::uint64_t, std::uint64_t)>& progress) {
  const std::uint64_t block = 16 * static_cast<std::uint64_t>(spec_.threads);
  std::vector<DatasetItem> items(block);
  for (std::uint64_t start = 0; start < spec_.count; start += block) {
    const std::uint64_t n = std::min(block, spec_.count - start);
    std::atomic<std::uint64_t> next{0};
    std::exception_ptr error;
    std::mutex error_mutex;
    auto work = [&] {
      for (std::uint64_t j; (j = next++) < n;) {
        try {
          DatasetItem& item = items[j];
          item.index = start + j;
          const std::uint64_t index = spec_.offset + item.index;
          item.instance = static_cast<int>(item.index % renderers_.size());
          item.image = renderers_[item.instance]->render(sampler_.sunVector(index), deriveSeed(spec_.seed, index),
                                                         &item.truth, spec_.render);
        } catch (...) {
          std::lock_guard<std::mutex> lock(error_mutex);
          error = std::current_exception();
        }
      }
    };
    std::vector<std::thread> pool;
    for (int t = 1; t < spec_.threads; ++t) pool.emplace_back(work);
    work();
    for (auto& th : pool) th.join();
    if (error) std::rethrow_exception(error);
    for (std::uint64_t j = 0; j < n; ++j) sink(items[j]);
    if (progress) progress(start + n, spec_.count);
  }
}

}  // namespace dss
