#include "digital_sun_sensor/ros/calibration_node.h"
#include "digital_sun_sensor/ros/node_runner.h"

int main(int argc, char** argv) { return dss::runNode<dss::CalibrationNode>(argc, argv, "calibration"); }
