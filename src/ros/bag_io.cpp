#include "digital_sun_sensor/ros/bag_io.h"

#include <geometry_msgs/Vector3Stamped.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <std_msgs/String.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <sstream>
#include <stdexcept>
#include <vector>

#include "digital_sun_sensor/common/limits.h"
#include "digital_sun_sensor/ros/conversions.h"

namespace dss {
namespace {

// The field lines of a message definition (comments, blank lines and
// constants dropped): what fixes the wire format.
std::vector<std::string> fieldLines(const std::string& definition) {
  std::vector<std::string> fields;
  std::istringstream in(definition);
  for (std::string line; std::getline(in, line);) {
    if (line.rfind("MSG:", 0) == 0 || line.rfind("===", 0) == 0) break;  // the embedded types follow
    const auto constant = line.find('=');
    line = line.substr(0, std::min(line.find('#'), constant));
    const auto first = line.find_first_not_of(" \t"), last = line.find_last_not_of(" \t");
    if (first == std::string::npos || constant != std::string::npos) continue;
    fields.push_back(line.substr(first, last - first + 1));
  }
  return fields;
}

// A SunAngles message, also from bags recorded before the message got its
// STATUS_* constants: constants change the type's MD5 sum (so rosbag refuses
// to instantiate it) but not the wire format, so a message whose recorded
// definition has the same fields is read from its bytes. Null otherwise.
boost::shared_ptr<digital_sun_sensor::SunAngles> instantiateSunAngles(const rosbag::MessageInstance& m) {
  using digital_sun_sensor::SunAngles;
  if (auto msg = m.instantiate<SunAngles>()) return msg;
  static const std::vector<std::string> current_fields =
      fieldLines(ros::message_traits::Definition<SunAngles>::value());
  if (m.getDataType() != ros::message_traits::DataType<SunAngles>::value() ||
      fieldLines(m.getMessageDefinition()) != current_fields)
    return nullptr;
  std::vector<std::uint8_t> bytes(m.size());
  ros::serialization::OStream out(bytes.data(), static_cast<std::uint32_t>(bytes.size()));
  m.write(out);
  auto msg = boost::make_shared<SunAngles>();
  ros::serialization::IStream in(bytes.data(), static_cast<std::uint32_t>(bytes.size()));
  ros::serialization::deserialize(in, *msg);
  return msg;
}

}  // namespace

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
    // Closing flushes, which throws on a full disk; a destructor must not
    // (the error that brought us here is already on its way). A bag whose
    // close failed would try again in its own destructor and end the
    // process: it is let go instead (its memory, once, on a failure).
    try {
      bag_->close();
    } catch (const rosbag::BagException&) {
      static_cast<void>(bag_.release());
    }
    std::remove(partial_.c_str());
  }
}

void DatasetBagWriter::write(const DatasetItem& item) {
  std_msgs::Header header;
  header.seq = static_cast<std::uint32_t>(item.index);
  header.stamp = start_ + ros::Duration(static_cast<double>(item.index) / rate_hz_);
  header.frame_id = topics_.frame_id;
  try {
    bag_->write(topics_.image, header.stamp, toImageMsg(item.image, header));
    bag_->write(topics_.truth, header.stamp, toTruthMsg(item.truth, config_, header));
    bag_->write(topics_.spots, header.stamp, toSpotsMsg(item.truth, header));
  } catch (const rosbag::BagException& e) {
    throw std::runtime_error("cannot write bag '" + partial_ + "' (image " + std::to_string(item.index) +
                             "; disk full?): " + e.what());
  }
}

void DatasetBagWriter::commit() {
  try {
    bag_->close();
  } catch (const rosbag::BagException& e) {
    throw std::runtime_error("cannot write bag '" + partial_ + "' (disk full?): " + e.what());
  }
  bag_.reset();
  if (std::rename(partial_.c_str(), path_.c_str()) != 0) {
    throw std::runtime_error("cannot rename '" + partial_ + "' to '" + path_ + "'");
  }
}

}  // namespace dss

namespace dss {

DatasetBagReader::DatasetBagReader(std::vector<std::string> paths, DatasetTopics topics)
    : paths_(std::move(paths)), topics_(std::move(topics)) {
  if (paths_.empty()) throw BagError("no bag given");
  for (const auto& path : paths_) {
    rosbag::Bag bag;
    try {
      bag.open(path, rosbag::bagmode::Read);
    } catch (const rosbag::BagException& e) {
      throw BagError("cannot read bag '" + path + "': " + e.what());
    }
    try {
      rosbag::View all(bag);
      std::vector<std::string> present;
      for (const auto* c : all.getConnections()) present.push_back(c->topic);
      for (const auto& needed : {topics_.image, topics_.truth}) {
        if (std::find(present.begin(), present.end(), needed) != present.end()) continue;
        std::string list;
        for (const auto& t : present) list += (list.empty() ? "" : ", ") + t;
        throw BagError("bag '" + path + "' has no messages on " + needed +
                       " (topics in it: " + (list.empty() ? "none" : list) + ")");
      }
      rosbag::View images(bag, rosbag::TopicQuery(topics_.image));
      image_messages_ += images.size();
      if (!info_yaml_) {
        rosbag::View info(bag, rosbag::TopicQuery(topics_.info));
        for (const auto& m : info) {
          if (const auto s = m.instantiate<std_msgs::String>()) info_yaml_ = s->data;
          break;
        }
      }
    } catch (const rosbag::BagException& e) {
      throw BagError("bag '" + path + "' is damaged: " + e.what());
    }
  }
}

BagReadStats DatasetBagReader::forEach(const std::function<bool(const LabelledImage&)>& sink) const {
  BagReadStats stats;
  for (const auto& path : paths_) {
    try {
      rosbag::Bag bag(path, rosbag::bagmode::Read);
      // Truth messages are small: index them by stamp, then stream the images.
      std::map<ros::Time, digital_sun_sensor::SunAngles> truths;
      for (const auto& m : rosbag::View(bag, rosbag::TopicQuery(topics_.truth))) {
        if (const auto t = instantiateSunAngles(m)) {
          truths[t->header.stamp] = *t;
        } else if (const auto v = m.instantiate<geometry_msgs::Vector3Stamped>()) {
          std::string why;
          if (const auto t = truthFromSunVector(*v, topics_.frame_id, why)) {
            truths[t->header.stamp] = *t;
          } else {
            if (stats.first_bad_truth.empty()) stats.first_bad_truth = why + " (on " + topics_.truth + ")";
            ++stats.bad_truths;
          }
        }
      }
      std::uint64_t matched_here = 0;
      for (const auto& m : rosbag::View(bag, rosbag::TopicQuery(topics_.image))) {
        auto bad = [&](const std::string& why) {
          if (stats.first_bad_image.empty()) stats.first_bad_image = why;
          ++stats.bad_images;
        };
        if (m.getDataType() != ros::message_traits::DataType<sensor_msgs::Image>::value() ||
            m.getMD5Sum() != ros::message_traits::MD5Sum<sensor_msgs::Image>::value()) {
          bad("a message on " + topics_.image + " is not an Image");
          continue;
        }
        // Read from the bytes with every length checked first (conversions.h).
        if (m.size() > limits::kMaxImageBytes + 65536) {
          bad("an image message of " + limits::describeBytes(m.size()) + " is over the limit of " +
              limits::describeBytes(limits::kMaxImageBytes));
          continue;
        }
        std::vector<std::uint8_t> bytes(m.size());
        ros::serialization::OStream out(bytes.data(), static_cast<std::uint32_t>(bytes.size()));
        m.write(out);
        sensor_msgs::Image msg;
        LabelledImage item;
        try {
          msg = imageMsgFromBytes(bytes.data(), bytes.size());
          item.image = imageFromMsg(msg);
        } catch (const std::invalid_argument& e) {
          bad(e.what());
          continue;
        }
        const auto truth = truths.find(msg.header.stamp);
        if (truth == truths.end()) {
          ++stats.unmatched_images;
          continue;
        }
        item.bag = path;
        item.index = stats.pairs++;
        item.stamp = msg.header.stamp;
        item.truth = truth->second;
        ++matched_here;
        if (!sink(item)) return stats;
      }
      stats.unmatched_truths += truths.size() - std::min<std::uint64_t>(truths.size(), matched_here);
    } catch (const rosbag::BagException& e) {
      throw BagError("bag '" + path + "' is damaged: " + e.what());
    }
  }
  return stats;
}

}  // namespace dss
