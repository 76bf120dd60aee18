#include "digital_sun_sensor/ros/node_params.h"

#include <ros/package.h>

#include <sstream>
#include <stdexcept>

namespace dss {

std::string resolveSensorConfigPath(const std::string& value) {
  if (value.find('/') != std::string::npos) return value;
  return ros::package::getPath("digital_sun_sensor") + "/config/sensors/" + value + ".yaml";
}

std::vector<std::string> stringListParam(const ros::NodeHandle& nh, const std::string& name) {
  XmlRpc::XmlRpcValue value;
  if (!nh.getParam(name, value)) return {};
  std::vector<std::string> items;
  if (value.getType() == XmlRpc::XmlRpcValue::TypeString) {
    std::istringstream words(static_cast<std::string>(value));
    for (std::string w; words >> w;) items.push_back(w);
  } else if (value.getType() == XmlRpc::XmlRpcValue::TypeArray) {
    for (int i = 0; i < value.size(); ++i) {
      if (value[i].getType() != XmlRpc::XmlRpcValue::TypeString)
        throw std::runtime_error("~" + name + " must be a list of strings");
      items.push_back(static_cast<std::string>(value[i]));
    }
  } else {
    throw std::runtime_error("~" + name + " must be a string or a list of strings");
  }
  return items;
}

}  // namespace dss
