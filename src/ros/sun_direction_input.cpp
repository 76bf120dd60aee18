#include "digital_sun_sensor/ros/sun_direction_input.h"

#include <tf2_geometry_msgs/tf2_geometry_msgs.h>

#include <cmath>
#include <stdexcept>

#include "digital_sun_sensor/sim/geometry.h"

namespace dss {
namespace {

constexpr std::size_t kKept = 200;  // recent directions waiting for their image

}  // namespace

SunDirectionInput::SunDirectionInput(ros::NodeHandle nh, const std::string& topic, double max_stamp_difference_s,
                                     std::string what)
    : what_(std::move(what)), max_stamp_difference_s_(max_stamp_difference_s), tf_listener_(tf_buffer_) {
  if (!(max_stamp_difference_s_ >= 0.0)) throw std::invalid_argument("the stamp tolerance must be >= 0");
  sub_ = nh.subscribe(topic, 100, &SunDirectionInput::onMessage, this);
}

void SunDirectionInput::onMessage(const geometry_msgs::Vector3Stamped::ConstPtr& msg) {
  std::lock_guard<std::mutex> lock(mutex_);
  recent_.push_back(msg);
  if (recent_.size() > kKept) recent_.pop_front();
  ++counts_.received;
}

std::optional<std::array<double, 2>> SunDirectionInput::forImage(const std_msgs::Header& image) {
  geometry_msgs::Vector3Stamped::ConstPtr best;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    double nearest = max_stamp_difference_s_;
    for (const auto& r : recent_) {
      const double d = std::abs((r->header.stamp - image.stamp).toSec());
      if (d <= nearest) nearest = d, best = r;
    }
    if (!best) {
      ++counts_.unpaired_images;
      return std::nullopt;
    }
  }
  geometry_msgs::Vector3Stamped in_sensor = *best;
  if (!best->header.frame_id.empty() && best->header.frame_id != image.frame_id) {
    try {
      in_sensor = tf_buffer_.transform(*best, image.frame_id, ros::Duration(0.0));
    } catch (const tf2::TransformException& e) {
      ROS_WARN_THROTTLE(5.0, "calibration_node: %s in frame '%s' not resolved to '%s': %s", what_.c_str(),
                        best->header.frame_id.c_str(), image.frame_id.c_str(), e.what());
      std::lock_guard<std::mutex> lock(mutex_);
      ++counts_.unresolved_frames;
      return std::nullopt;
    }
  }
  const auto& v = in_sensor.vector;
  std::lock_guard<std::mutex> lock(mutex_);
  if (!(v.z > 0.0) || !std::isfinite(v.x) || !std::isfinite(v.y) || !std::isfinite(v.z)) {
    ++counts_.behind_sensor;
    return std::nullopt;
  }
  ++counts_.paired;
  const SunAnglesRad angles = anglesFromSunVector(Eigen::Vector3d(v.x, v.y, v.z));
  return std::array<double, 2>{angles.alpha, angles.beta};
}

SunDirectionInput::Counts SunDirectionInput::counts() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return counts_;
}

}  // namespace dss
