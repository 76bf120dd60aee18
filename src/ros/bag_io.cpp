#include "digital_sun_sensor/ros/bag_io.h"

#include "digital_sun_sensor/ros/conversions.h"

#include <rosbag/bag.h>
#include <std_msgs/String.h>

#include <cstdio>
#include <stdexcept>

namespace dss {

DatasetBagWriter::DatasetBagWriter(const std::string& path, const SensorConfig& config, const std::string& info_yaml,
                                   double rate_hz, const DatasetTopics& topics, ros::Time start)
    : path_(path), partial_(path + ".partial"), config_(config), topics_(topics), rate_hz_(rate_hz), start_(start) {
  if (!(rate_hz > 0.0)) throw std::invalid_argument("bag stamp rate must be > 0");
  if (!ros::Time::isValid()) ros::Time::init();
  bag_ = std::make_unique<rosbag::Bag>();
  try {
    bag_->open(partial_, rosbag::bagmode::Write);
  } catch (const rosbag::BagException& e) {
    throw std::runtime_error("cannot write bag '" + partial_ + "': " + e.what());
  }
  std_msgs::String info;
  info.data = info_yaml;
  bag_->write(topics_.info, start_, info);
}

DatasetBagWriter::~DatasetBagWriter() {
  if (bag_) {
    bag_->close();
    std::remove(partial_.c_str());
  }
}

void DatasetBagWriter::write(const DatasetItem& item) {
  std_msgs::Header header;
  header.seq = static_cast<std::uint32_t>(item.index);
  header.stamp = start_ + ros::Duration(static_cast<double>(item.index) / rate_hz_);
  header.frame_id = topics_.frame_id;
  bag_->write(topics_.image, header.stamp, toImageMsg(item.image, header));
  bag_->write(topics_.truth, header.stamp, toTruthMsg(item.truth, config_, header));
  bag_->write(topics_.spots, header.stamp, toSpotsMsg(item.truth, header));
}

void DatasetBagWriter::commit() {
  bag_->close();
  bag_.reset();
  if (std::rename(partial_.c_str(), path_.c_str()) != 0) {
    throw std::runtime_error("cannot rename '" + partial_ + "' to '" + path_ + "'");
  }
}

}  // namespace dss
