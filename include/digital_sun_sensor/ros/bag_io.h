// Dataset rosbags: /sun_sensor/image + /sun_sensor/truth (+ /sun_sensor/truth_spots),
// and a /sun_sensor/dataset_info YAML string with provenance (sensor config,
// seeds, sampling). Written to "<path>.partial" and renamed when complete, so
// an interrupted run never leaves a bag that looks finished.
#pragma once

#include <digital_sun_sensor/SunAngles.h>
#include <ros/time.h>

#include <functional>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "digital_sun_sensor/sim/dataset_generator.h"

namespace rosbag {
class Bag;
}

namespace dss {

struct DatasetTopics {
  std::string image = "/sun_sensor/image";
  std::string truth = "/sun_sensor/truth";
  std::string spots = "/sun_sensor/truth_spots";
  std::string info = "/sun_sensor/dataset_info";
  std::string frame_id = "sun_sensor_link";
};

class DatasetBagWriter {
 public:
  // Stamps: start + index / rate_hz. A fixed start keeps bags reproducible.
  DatasetBagWriter(const std::string& path, const SensorConfig& config, const std::string& info_yaml,
                   double rate_hz = 10.0, const DatasetTopics& topics = {}, ros::Time start = ros::Time(1700000000, 0));
  ~DatasetBagWriter();  // without commit(): removes the partial file

  void write(const DatasetItem& item);
  void commit();  // close and rename into place

 private:
  std::string path_;
  std::string partial_;
  SensorConfig config_;
  DatasetTopics topics_;
  double rate_hz_;
  ros::Time start_;
  std::unique_ptr<rosbag::Bag> bag_;
};

// A bag that cannot be used: unreadable, truncated, or without the topics.
class BagError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// One image with its ground truth (matched by header stamp).
struct LabelledImage {
  std::string bag;
  std::uint64_t index = 0;  // position among the matched pairs of all bags
  ros::Time stamp;
  cv::Mat image;  // CV_8U (mono8) or CV_16U (mono16), shares no memory with the bag
  digital_sun_sensor::SunAngles truth;
};

struct BagReadStats {
  std::uint64_t pairs = 0;
  std::uint64_t unmatched_images = 0;  // no truth with the same stamp
  std::uint64_t unmatched_truths = 0;
  std::uint64_t bad_images = 0;  // wrong encoding or a data buffer that disagrees with the size
  std::string first_bad_image;   // why the first bad image was skipped
  std::uint64_t bad_truths = 0;  // sun vectors in another frame, zero or not finite
  std::string first_bad_truth;
};

// Reads image/truth pairs from one or more dataset bags. Opening checks every
// bag and its topics up front, so problems surface before any work starts.
class DatasetBagReader {
 public:
  // Throws BagError naming the bag and the problem.
  explicit DatasetBagReader(std::vector<std::string> paths, DatasetTopics topics = {});

  // The first bag's /sun_sensor/dataset_info YAML, when present.
  const std::optional<std::string>& infoYaml() const { return info_yaml_; }
  // Number of image messages in all bags (an upper bound on the pairs).
  std::uint64_t imageMessages() const { return image_messages_; }

  // Calls `sink` for every matched pair, bag by bag in stamp order. Return
  // false from the sink to stop early.
  BagReadStats forEach(const std::function<bool(const LabelledImage&)>& sink) const;

 private:
  std::vector<std::string> paths_;
  DatasetTopics topics_;
  std::optional<std::string> info_yaml_;
  std::uint64_t image_messages_ = 0;
};

}  // namespace dss
