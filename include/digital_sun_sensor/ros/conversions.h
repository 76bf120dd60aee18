// Core types <-> ROS messages.
#pragma once

#include "digital_sun_sensor/sim/renderer.h"

#include <digital_sun_sensor/SpotCentres.h>
#include <digital_sun_sensor/SunAngles.h>
#include <sensor_msgs/Image.h>

#include <string>

namespace dss {

using SunAngles = digital_sun_sensor::SunAngles;
using SpotCentres = digital_sun_sensor::SpotCentres;

// mono8 for CV_8U, mono16 for CV_16U; throws std::invalid_argument otherwise.
sensor_msgs::Image toImageMsg(const cv::Mat& image, const std_msgs::Header& header);

// A copy of a mono8 / mono16 image (CV_8U / CV_16U); throws
// std::invalid_argument naming the problem (encoding, size, short buffer).
cv::Mat imageFromMsg(const sensor_msgs::Image& msg);

SunAngles toTruthMsg(const ImageTruth& truth, const SensorConfig& config, const std_msgs::Header& header);
SpotCentres toSpotsMsg(const ImageTruth& truth, const std_msgs::Header& header);

// True when the sun lies inside the config's field of view.
bool insideFieldOfView(const SensorConfig& config, double alpha_rad, double beta_rad);

}  // namespace dss
