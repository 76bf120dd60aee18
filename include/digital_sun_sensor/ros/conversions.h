// Core types <-> ROS messages.
#pragma once

#include <digital_sun_sensor/SpotCentres.h>
#include <digital_sun_sensor/SunAngles.h>
#include <geometry_msgs/Vector3Stamped.h>
#include <sensor_msgs/Image.h>

#include <cstdint>
#include <optional>
#include <string>

#include "digital_sun_sensor/sim/renderer.h"

namespace dss {

using SunAngles = digital_sun_sensor::SunAngles;
using SpotCentres = digital_sun_sensor::SpotCentres;

// mono8 for CV_8U, mono16 for CV_16U; throws std::invalid_argument otherwise.
sensor_msgs::Image toImageMsg(const cv::Mat& image, const std_msgs::Header& header);

// A copy of a mono8 / mono16 image (CV_8U / CV_16U); throws
// std::invalid_argument naming the problem (encoding, size, short buffer).
cv::Mat imageFromMsg(const sensor_msgs::Image& msg);

// A sensor_msgs/Image from its serialized bytes (a bag's payload). Every
// length field is checked against the bytes left, and the data against
// limits::kMaxImageBytes, before anything is allocated (ROS's deserializer
// sizes the data vector from its length field first). Throws
// std::invalid_argument naming the problem.
sensor_msgs::Image imageMsgFromBytes(const std::uint8_t* bytes, std::size_t size);

// Lab truth given as a sun vector: the angles of a vector in the sensor frame
// (`sensor_frame`, or no frame). Null, with `why` set, for another frame or a
// zero or non-finite vector.
std::optional<SunAngles> truthFromSunVector(const geometry_msgs::Vector3Stamped& vector,
                                            const std::string& sensor_frame, std::string& why);

// The unit sun vector of the angles (sensor frame of `header`): what
// calibration_node publishes, and what a reference or coarse sun direction carries.
geometry_msgs::Vector3Stamped toSunVectorMsg(double alpha_rad, double beta_rad, const std_msgs::Header& header);

SunAngles toTruthMsg(const ImageTruth& truth, const SensorConfig& config, const std_msgs::Header& header);
SpotCentres toSpotsMsg(const ImageTruth& truth, const std_msgs::Header& header);

// True when the sun lies inside the config's field of view.
bool insideFieldOfView(const SensorConfig& config, double alpha_rad, double beta_rad);

}  // namespace dss
