// Shared by the front ends that read dataset bags (dss calibrate/eval/train,
// trainer_node): the sensor config a bag was rendered from, the check that its
// images fit a sensor, and loading bags into a training set.
#pragma once

#include <functional>
#include <optional>
#include <string>

#include "digital_sun_sensor/ros/bag_io.h"
#include "digital_sun_sensor/train/training_set.h"

namespace dss {

// The sensor config embedded in a bag's dataset_info, if any.
std::optional<SensorConfig> sensorFromBagInfo(const DatasetBagReader& reader);
// Sensor instances the bag was rendered from (1 when not recorded).
int instancesFromBagInfo(const DatasetBagReader& reader);
// The one sensor a `dss generate` bag was rendered from, drawn again from its
// seed (a built unit: --anomalies as_built=K); std::runtime_error when the bag
// records no dataset_info or several sensors.
SensorInstance drawnSensorFromBagInfo(const DatasetBagReader& reader);

// Throws std::runtime_error naming the bag, the image and both sizes when an
// image does not fit the sensor.
void checkImageFitsSensor(const LabelledImage& item, const SensorConfig& config);

// "N pairs; M images without truth, ..." for stderr.
std::string describe(const BagReadStats& stats);

struct TrainingData {
  SensorConfig sensor;
  TrainingSet samples{InputSpec{}};
  BagReadStats stats;
  std::uint64_t wrong_size_images = 0;  // skipped: they do not fit the sensor
  std::string first_wrong_size;          // why the first was skipped
};

// Reads every image/truth pair of `bags` into a training set for `sensor`
// (default: the sensor recorded in the first bag's dataset_info). Images
// that do not fit the sensor are counted and skipped. Throws BagError or
// std::runtime_error naming the problem when there is no sensor config or
// no usable pair. `progress(done, total)` is called as images are read.
TrainingData loadTrainingData(const std::vector<std::string>& bags, const std::optional<SensorConfig>& sensor,
                              const DatasetTopics& topics = {}, std::uint64_t max_images = 0,
                              const std::function<void(std::uint64_t, std::uint64_t)>& progress = {});

// "N pairs; M images without truth, ..., K images of the wrong size skipped".
std::string describe(const TrainingData& data);

}  // namespace dss
