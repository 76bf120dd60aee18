#include "digital_sun_sensor/ros/pipeline_bench.h"

int main(int argc, char** argv) {
  ros::init(argc, argv, "pipeline_bench");
  try {
    dss::PipelineBench bench(ros::NodeHandle(), ros::NodeHandle("~"));
    ros::spin();  // until the bench has printed its report and requested shutdown
  } catch (const std::exception& e) {
    ROS_FATAL("pipeline_bench: %s", e.what());
    return 1;
  }
  return 0;
}
