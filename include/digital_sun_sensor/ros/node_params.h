// Parameter helpers shared by the nodes.
#pragma once

#include <ros/node_handle.h>

#include <string>
#include <vector>

namespace dss {

// A bare name ("thesis_sa") means the shipped config/sensors/<name>.yaml; a
// value with a '/' is a path.
std::string resolveSensorConfigPath(const std::string& value);

// A list parameter given either as a YAML list or as one whitespace-separated
// string (what `roslaunch ... bags:="a.bag b.bag"` passes). Empty when unset.
// Throws std::runtime_error naming the parameter when it is neither.
std::vector<std::string> stringListParam(const ros::NodeHandle& nh, const std::string& name);

}  // namespace dss
