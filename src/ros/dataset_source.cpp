#include "digital_sun_sensor/ros/dataset_source.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <sstream>
#include <stdexcept>

#include "digital_sun_sensor/baseline/calibration_model.h"
#include "digital_sun_sensor/common/yaml_reader.h"
#include "digital_sun_sensor/sim/dataset_generator.h"
#include "digital_sun_sensor/sim/geometry.h"
#include "digital_sun_sensor/sim/renderer.h"

namespace dss {

std::optional<SensorConfig> sensorFromBagInfo(const DatasetBagReader& reader) {
  if (!reader.infoYaml()) return std::nullopt;
  try {
    const YAML::Node info = loadYaml(*reader.infoYaml(), "the bag's dataset_info");
    if (!info["sensor"]) return std::nullopt;
    return parseSensorConfig(YAML::Dump(info["sensor"]), "the bag's dataset_info");
  } catch (const YAML::Exception& e) {
    throw std::runtime_error(std::string("the bag's dataset_info is not valid YAML: ") + e.what());
  } catch (const YamlError& e) {
    throw std::runtime_error(e.what());
  }
}

int instancesFromBagInfo(const DatasetBagReader& reader) {
  if (!reader.infoYaml()) return 1;
  try {
    const YAML::Node info = loadYaml(*reader.infoYaml(), "the bag's dataset_info");
    return info["instances"] ? info["instances"].as<int>() : 1;
  } catch (const std::exception&) {
    return 1;
  }
}

SensorInstance drawnSensorFromBagInfo(const DatasetBagReader& reader) {
  const std::optional<SensorConfig> config = sensorFromBagInfo(reader);
  const YAML::Node info = reader.infoYaml() ? loadYaml(*reader.infoYaml(), "the bag's dataset_info") : YAML::Node();
  if (!config || !info["seed"]) throw std::runtime_error("the bag records no dataset_info with its sensor and seed");
  if (const int instances = instancesFromBagInfo(reader); instances != 1)
    throw std::runtime_error("the bag was rendered from " + std::to_string(instances) + " sensor instances, not one");
  return SensorInstance::draw(*config, DatasetGenerator::instanceSeed(info["seed"].as<std::uint64_t>(), 0));
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
  if (stats.bad_truths)
    os << "; " << stats.bad_truths << " unusable truths skipped (first: " << stats.first_bad_truth << ")";
  return os.str();
}

namespace {

// Sub-FOV class of the sensor's design at the angles: the quadrant, or the
// aperture whose spot is nearest the detector centre.
int designSubFovClass(const SensorConfig& config, double alpha_rad, double beta_rad) {
  ImageTruth truth;
  truth.alpha_rad = alpha_rad;
  truth.beta_rad = beta_rad;
  truth.sun = sunVectorFromAngles(alpha_rad, beta_rad);
  const MaskGeometry design = MaskGeometry::nominalOf(config);
  for (int k = 0; k < design.numApertures(); ++k)
    if (const auto spot = design.spotPx(k, truth.sun)) {
      SpotTruth s;
      s.aperture_index = k;
      s.x_px = spot->x();
      s.y_px = spot->y();
      truth.spots.push_back(s);
    }
  return subFovClass(config, truth);
}

}  // namespace

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
      // Truth given as a sun vector carries no class: the design's.
      const int subfov_class = item.truth.subfov_class >= 0
                                   ? item.truth.subfov_class
                                   : designSubFovClass(data.sensor, item.truth.alpha, item.truth.beta);
      data.samples.add(item.image, item.truth.alpha, item.truth.beta, subfov_class);
    } catch (const std::exception& e) {
      if (data.wrong_size_images++ == 0) data.first_wrong_size = e.what();
    }
    if (progress) progress(item.index + 1, total);
    return max_images == 0 || item.index + 1 < max_images;
  });
  if (data.samples.size() == 0) throw std::runtime_error("no usable image/truth pairs in the data: " + describe(data));
  return data;
}

std::string describe(const TrainingData& data) {
  std::string text = describe(data.stats);
  if (data.wrong_size_images)
    text += "; " + std::to_string(data.wrong_size_images) +
            " images that do not fit the sensor skipped (first: " + data.first_wrong_size + ")";
  return text;
}

}  // namespace dss
