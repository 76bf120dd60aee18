#include "digital_sun_sensor/ros/node_runner.h"
#include "digital_sun_sensor/ros/pipeline_bench.h"

int main(int argc, char** argv) { return dss::runNode<dss::PipelineBench>(argc, argv, "pipeline_bench"); }
