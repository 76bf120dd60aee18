#include "digital_sun_sensor/ros/dataset_source.h"

#include <yaml-cpp/yaml.h>

#include <sstream>
#include <algorithm>
#include <stdexcept>

namespace dss {

std::optional<SensorConfig> sensorFromBagInfo(const DatasetBagReader& reader) {
  if (!reader.infoYaml()) return std::nullopt;
  try {
    const YAML::Node info = YAML::Load(*reader.infoYaml());
    if (!info["sensor"]) return std::nullopt;
    return parseSensorConfig(YAML::Dump(info["sensor"]), "the bag's dataset_info");
  } catch (const YAML::Exception& e) {
    throw std::runtime_error(std::string("the bag's dataset_info is not valid YAML: ") + e.what());
  }
}

int instancesFromBagInfo(const DatasetBagReader& reader) {
  if (!reader.infoYaml()) return 1;
  try {
    const YAML::Node info = YAML::Load(*reader.infoYaml());
    return info["instances"] ? info["instances"].as<int>() : 1;
  } catch (const YAML::Exception&) {
    return 1;
  }
}

void checkImageFitsSensor(const LabelledImage& item, const SensorConfig& config) {
  const int bits = item.image.depth() == CV_8U ? 8 : 16;
  if (item.image.cols == config.detector.width_px && item.image.rows == config.detector.height_px &&
      (bits == 8) == (config.noise.bit_depth <= 8))
    return;
  std::ostringstream os;
  os << "image " << item.index << " of '" << item.bag << "' (stamp " << item.stamp << ") is " << item.image.cols << "x"
     << item.image.rows << " " << (bits == 8 ? "mono8" : "mono16") << " but the sensor '" << config.name << "' is "
     << config.detector.width_px << "x" << config.detector.height_px << " "
     << (config.noise.bit_depth <= 8 ? "mono8" : "mono16");
  throw std::runtime_error(os.str());
}

std::string describe(const BagReadStats& stats) {
  std::ostringstream os;
  os << stats.pairs << " image/truth pairs";
  if (stats.unmatched_images) os << "; " << stats.unmatched_images << " images without truth";
  if (stats.unmatched_truths) os << "; " << stats.unmatched_truths << " truths without image";
  if (stats.bad_images)
    os << "; " << stats.bad_images << " unreadable images skipped (first: " << stats.first_bad_image << ")";
  return os.str();
}

TrainingData loadTrainingData(const std::vector<std::string>& bags, const std::optional<SensorConfig>& sensor,
                              const DatasetTopics& topics, std::uint64_t max_images,
                              const std::function<void(std::uint64_t, std::uint64_t)>& progress) {
  const DatasetBagReader reader(bags, topics);
  std::optional<SensorConfig> config = sensor ? sensor : sensorFromBagInfo(reader);
  if (!config)
    throw std::runtime_error("'" + bags.front() +
                             "' records no sensor config (no dataset_info): name the sensor config explicitly");
  TrainingData data;
  data.sensor = *config;
  data.samples = TrainingSet(inputSpecFor(data.sensor));
  const std::uint64_t total = max_images ? std::min(max_images, reader.imageMessages()) : reader.imageMessages();
  data.stats = reader.forEach([&](const LabelledImage& item) {
    try {
      checkImageFitsSensor(item, data.sensor);
      data.samples.add(item.image, item.truth.alpha, item.truth.beta, item.truth.subfov_class);
    } catch (const std::exception& e) {
      if (data.wrong_size_images++ == 0) data.first_wrong_size = e.what();
    }
    if (progress) progress(item.index + 1, total);
    return max_images == 0 || item.index + 1 < max_images;
  });
  if (data.samples.size() == 0)
    throw std::runtime_error("no usable image/truth pairs in the data: " + describe(data));
  return data;
}

std::string describe(const TrainingData& data) {
  std::string text = describe(data.stats);
  if (data.wrong_size_images)
    text += "; " + std::to_string(data.wrong_size_images) + " images that do not fit the sensor skipped (first: " +
            data.first_wrong_size + ")";
  return text;
}

}  // namespace dss
