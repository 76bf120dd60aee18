#include "bag_reading.h"

#include <iostream>
#include <memory>

#include "progress.h"

namespace dss::cli {

TrainingData readLabelledBags(const std::string& verb, const std::vector<std::string>& bags,
                              const std::optional<SensorConfig>& sensor, const DatasetTopics& topics,
                              std::uint64_t max_images) {
  std::unique_ptr<Progress> reading;
  TrainingData data = loadTrainingData(bags, sensor, topics, max_images, [&](std::uint64_t done, std::uint64_t total) {
    if (!reading) reading = std::make_unique<Progress>(verb + ": reading bags", total);
    reading->update(done);
  });
  if (reading) reading->finish();
  std::cerr << "read " << describe(data) << "\n";
  return data;
}

}  // namespace dss::cli
