// Message payloads as the dataset bag reader sees them (dss train, calibrate,
// eval, trainer_node): the first byte says which topic's message the rest is.
//   0: a sensor_msgs/Image (bounded deserializer, then the image copy);
//   1: a SunAngles truth;
//   2: a geometry_msgs/Vector3Stamped sun vector (lab truth).
#include <ros/serialization.h>

#include "digital_sun_sensor/ros/conversions.h"
#include "fuzz_entry.h"

namespace {

template <typename Msg>
bool deserializeFrom(const std::uint8_t* data, std::size_t size, Msg& msg) {
  try {
    ros::serialization::IStream in(const_cast<std::uint8_t*>(data), static_cast<std::uint32_t>(size));
    ros::serialization::deserialize(in, msg);
    return true;
  } catch (const ros::serialization::StreamOverrunException&) {
    return false;
  }
}

}  // namespace

extern "C" int DSS_FUZZ_ENTRY(const std::uint8_t* data, std::size_t size) {
  if (size < 1) return 0;
  const std::uint8_t* payload = data + 1;
  const std::size_t bytes = size - 1;
  switch (data[0] % 3) {
    case 0:
      try {
        dss::imageFromMsg(dss::imageMsgFromBytes(payload, bytes));
      } catch (const std::invalid_argument&) {
      }
      break;
    case 1: {
      dss::SunAngles truth;
      deserializeFrom(payload, bytes, truth);
      break;
    }
    default: {
      geometry_msgs::Vector3Stamped vector;
      std::string why;
      if (deserializeFrom(payload, bytes, vector)) dss::truthFromSunVector(vector, "sun_sensor_link", why);
    }
  }
  return 0;
}
