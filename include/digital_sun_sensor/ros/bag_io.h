// Dataset rosbags: /sun_sensor/image + /sun_sensor/truth (+ /sun_sensor/truth_spots),
// and a /sun_sensor/dataset_info YAML string with provenance (sensor config,
// seeds, sampling). Written to "<path>.partial" and renamed when complete, so
// an interrupted run never leaves a bag that looks finished.
#pragma once

#include "digital_sun_sensor/sim/dataset_generator.h"

#include <ros/time.h>

#include <memory>
#include <string>

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
                   double rate_hz = 10.0, const DatasetTopics& topics = {},
                   ros::Time start = ros::Time(1700000000, 0));
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

}  // namespace dss
