// A stream of sun directions (geometry_msgs/Vector3Stamped in any frame tf
// resolves to the image's) paired with images by stamp: calibration_node's
// in-flight references (~recalibration) and coarse sun sensor readings
// (~coarse_sun). Bounded memory; thread-safe.
#pragma once

#include <geometry_msgs/Vector3Stamped.h>
#include <ros/ros.h>
#include <std_msgs/Header.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_listener.h>

#include <array>
#include <cstdint>
#include <deque>
#include <mutex>
#include <optional>
#include <string>

namespace dss {

class SunDirectionInput {
 public:
  // Subscribes to `topic` on `nh`; `what` names the stream in warnings.
  SunDirectionInput(ros::NodeHandle nh, const std::string& topic, double max_stamp_difference_s, std::string what);

  // The direction of the nearest stamp within the tolerance, as (alpha, beta)
  // [rad] in the image's frame; none when no direction lies that near, tf
  // cannot resolve its frame, or it points away from the sensor (counted).
  std::optional<std::array<double, 2>> forImage(const std_msgs::Header& image);

  struct Counts {
    std::uint64_t received = 0, paired = 0, unpaired_images = 0, unresolved_frames = 0, behind_sensor = 0;
  };
  Counts counts() const;

 private:
  void onMessage(const geometry_msgs::Vector3Stamped::ConstPtr& msg);

  std::string what_;
  double max_stamp_difference_s_;
  tf2_ros::Buffer tf_buffer_;
  tf2_ros::TransformListener tf_listener_;
  mutable std::mutex mutex_;
  std::deque<geometry_msgs::Vector3Stamped::ConstPtr> recent_;
  Counts counts_;
  ros::Subscriber sub_;  // last: unsubscribed first, before what its callback touches goes
};

}  // namespace dss
