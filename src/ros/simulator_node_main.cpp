#include "digital_sun_sensor/ros/node_runner.h"
#include "digital_sun_sensor/ros/simulator_node.h"

int main(int argc, char** argv) { return dss::runNode<dss::SimulatorNode>(argc, argv, "simulator"); }
