#include "digital_sun_sensor/ros/simulator_node.h"


int main(int argc, char** argv) {
  ros::init(argc, argv, "simulator");
  try {
    dss::SimulatorNode node(ros::NodeHandle(), ros::NodeHandle("~"));
    ros::spin();
  } catch (const std::exception& e) {
    ROS_FATAL("simulator_node: %s", e.what());
    return 1;
  }
  return 0;
}
