// Labelled bags into memory for a dss verb, with a progress bar and a
// summary line on stderr (the verbs that read image/truth pairs share it).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "digital_sun_sensor/ros/dataset_source.h"

namespace dss::cli {

// loadTrainingData with "VERB: reading bags" progress, then "read ..." on stderr.
TrainingData readLabelledBags(const std::string& verb, const std::vector<std::string>& bags,
                              const std::optional<SensorConfig>& sensor, const DatasetTopics& topics,
                              std::uint64_t max_images);

}  // namespace dss::cli
