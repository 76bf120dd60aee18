#include "dataset_source.h"

#include <yaml-cpp/yaml.h>

#include <sstream>
#include <stdexcept>

namespace dss::cli {

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

}  // namespace dss::cli
