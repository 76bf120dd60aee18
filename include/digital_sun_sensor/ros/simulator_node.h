// simulator_node: publishes simulated sun sensor images and ground truth at a
// fixed rate. The sun direction comes from /attitude (body -> inertial) with
// the inertial sun direction parameter and the sensor mounting from tf, or,
// while no attitude arrives, from a built-in profile (fixed, slew, raster,
// random). Used by both the node executable and the nodelet.
#pragma once

#include <diagnostic_updater/diagnostic_updater.h>
#include <diagnostic_updater/publisher.h>
#include <geometry_msgs/QuaternionStamped.h>
#include <ros/ros.h>
#include <tf2_ros/transform_listener.h>

#include <memory>
#include <mutex>
#include <string>

#include "digital_sun_sensor/sim/renderer.h"

namespace dss {

class SimulatorNode {
 public:
  // Reads parameters from `pnh`; throws std::runtime_error with a clear
  // message on a bad sensor config or parameter.
  SimulatorNode(ros::NodeHandle nh, ros::NodeHandle pnh);

 private:
  void onAttitude(const geometry_msgs::QuaternionStamped::ConstPtr& msg);
  void onTimer(const ros::TimerEvent& event);
  Eigen::Vector3d profileSun(double t_s);
  bool attitudeSun(Eigen::Vector3d* sun_sensor);
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat);

  ros::NodeHandle nh_, pnh_;
  std::unique_ptr<Renderer> renderer_;
  std::string frame_id_, body_frame_, profile_;
  double rate_hz_ = 10.0;
  double attitude_timeout_s_ = 1.0;
  Eigen::Vector3d sun_inertial_ = Eigen::Vector3d::UnitX();
  double fixed_alpha_rad_ = 0.0, fixed_beta_rad_ = 0.0;
  double slew_rate_rad_s_ = 0.0, slew_heading_rad_ = 0.0;
  double raster_step_rad_ = 0.0;
  std::uint64_t seed_ = 0, frame_count_ = 0;
  bool publish_spots_ = true;

  tf2_ros::Buffer tf_buffer_;
  std::unique_ptr<tf2_ros::TransformListener> tf_listener_;
  std::mutex attitude_mutex_;
  geometry_msgs::QuaternionStamped::ConstPtr last_attitude_;
  ros::Time start_;

  ros::Publisher image_pub_, truth_pub_, spots_pub_;
  ros::Subscriber attitude_sub_;
  ros::Timer timer_;
  diagnostic_updater::Updater updater_;
  std::unique_ptr<diagnostic_updater::FrequencyStatus> rate_status_;
  double min_rate_hz_ = 0.0, max_rate_hz_ = 0.0;
  double last_render_ms_ = 0.0;
  bool last_from_attitude_ = false, last_in_fov_ = true;
  std::string last_warning_;
  std::size_t dropped_at_last_diagnosis_ = 0;  // diffraction nodes dropped for memory
};

}  // namespace dss
