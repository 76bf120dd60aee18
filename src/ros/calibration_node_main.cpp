#include "digital_sun_sensor/ros/calibration_node.h"

int main(int argc, char** argv) {
  ros::init(argc, argv, "calibration");
  try {
    dss::CalibrationNode node(ros::NodeHandle(), ros::NodeHandle("~"));
    ros::spin();
  } catch (const std::exception& e) {
    ROS_FATAL("calibration_node: %s", e.what());
    return 1;
  }
  return 0;
}
