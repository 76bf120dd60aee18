#include "digital_sun_sensor/ros/conversions.h"

#include <ros/serialization.h>

#include <cmath>
#include <cstring>
#include <stdexcept>

#include "digital_sun_sensor/common/estimate_status.h"
#include "digital_sun_sensor/common/limits.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/sim/geometry.h"

namespace dss {

sensor_msgs::Image toImageMsg(const cv::Mat& image, const std_msgs::Header& header) {
  sensor_msgs::Image msg;
  msg.header = header;
  msg.height = static_cast<std::uint32_t>(image.rows);
  msg.width = static_cast<std::uint32_t>(image.cols);
  if (image.type() == CV_8UC1) {
    msg.encoding = "mono8";
  } else if (image.type() == CV_16UC1) {
    msg.encoding = "mono16";
  } else {
    throw std::invalid_argument("toImageMsg: only CV_8UC1 and CV_16UC1 images are supported");
  }
  msg.is_bigendian = 0;
  msg.step = static_cast<std::uint32_t>(image.cols * image.elemSize());
  msg.data.resize(static_cast<std::size_t>(msg.step) * image.rows);
  for (int r = 0; r < image.rows; ++r) std::memcpy(&msg.data[r * msg.step], image.ptr(r), msg.step);
  return msg;
}

cv::Mat imageFromMsg(const sensor_msgs::Image& msg) {
  int type = -1;
  if (msg.encoding == "mono8" || msg.encoding == "8UC1") type = CV_8UC1;
  if (msg.encoding == "mono16" || msg.encoding == "16UC1") type = CV_16UC1;
  if (type < 0) throw std::invalid_argument("encoding '" + msg.encoding + "' is not mono8 or mono16");
  if (msg.width == 0 || msg.height == 0) throw std::invalid_argument("image has zero width or height");
  if (msg.width > limits::kMaxDetectorSidePx || msg.height > limits::kMaxDetectorSidePx)
    throw std::invalid_argument("image is " + std::to_string(msg.width) + "x" + std::to_string(msg.height) +
                                ", over the limit of " + std::to_string(limits::kMaxDetectorSidePx) + " px a side");
  if (msg.data.size() > limits::kMaxImageBytes ||
      static_cast<std::uint64_t>(msg.step) * msg.height > limits::kMaxImageBytes)
    throw std::invalid_argument("image data over the limit of " + limits::describeBytes(limits::kMaxImageBytes));
  const std::size_t bytes_per_px = type == CV_8UC1 ? 1 : 2;
  if (msg.step < msg.width * bytes_per_px)
    throw std::invalid_argument("row step " + std::to_string(msg.step) + " is shorter than " +
                                std::to_string(msg.width) + " pixels");
  if (msg.data.size() < static_cast<std::size_t>(msg.step) * msg.height)
    throw std::invalid_argument("data holds " + std::to_string(msg.data.size()) + " bytes, " +
                                std::to_string(msg.width) + "x" + std::to_string(msg.height) + " " + msg.encoding +
                                " needs " + std::to_string(static_cast<std::size_t>(msg.step) * msg.height));
  cv::Mat image(static_cast<int>(msg.height), static_cast<int>(msg.width), type);
  for (int r = 0; r < image.rows; ++r) std::memcpy(image.ptr(r), &msg.data[r * msg.step], msg.width * bytes_per_px);
  // Host byte order is little-endian here; swap big-endian 16-bit data.
  if (type == CV_16UC1 && msg.is_bigendian) {
    for (int r = 0; r < image.rows; ++r) {
      auto* p = image.ptr<std::uint16_t>(r);
      for (int c = 0; c < image.cols; ++c) p[c] = static_cast<std::uint16_t>((p[c] >> 8) | (p[c] << 8));
    }
  }
  return image;
}

sensor_msgs::Image imageMsgFromBytes(const std::uint8_t* bytes, std::size_t size) {
  // The wire format: header (seq, stamp, frame_id), height, width, encoding,
  // is_bigendian, step, data; strings and data carry a u32 length first.
  std::size_t at = 0;
  auto skip = [&](std::size_t n, const char* field) {
    if (n > size - at) throw std::invalid_argument(std::string("image message is truncated in '") + field + "'");
    at += n;
  };
  auto u32 = [&](const char* field) {
    std::uint32_t v = 0;
    const std::size_t start = at;
    skip(4, field);
    std::memcpy(&v, bytes + start, 4);
    return v;
  };
  skip(12, "header");
  skip(u32("header.frame_id"), "header.frame_id");
  skip(8, "height, width");
  skip(u32("encoding"), "encoding");
  skip(5, "is_bigendian, step");
  const std::uint32_t data_bytes = u32("data");
  if (data_bytes > limits::kMaxImageBytes)
    throw std::invalid_argument("image data of " + limits::describeBytes(data_bytes) + " over the limit of " +
                                limits::describeBytes(limits::kMaxImageBytes));
  skip(data_bytes, "data");
  if (at != size) throw std::invalid_argument("image message has " + std::to_string(size - at) + " bytes past its end");
  sensor_msgs::Image msg;
  ros::serialization::IStream in(const_cast<std::uint8_t*>(bytes), static_cast<std::uint32_t>(size));
  ros::serialization::deserialize(in, msg);
  return msg;
}

std::optional<SunAngles> truthFromSunVector(const geometry_msgs::Vector3Stamped& v, const std::string& sensor_frame,
                                            std::string& why) {
  // A bag holds no transforms: only the sensor frame can be resolved.
  if (!v.header.frame_id.empty() && v.header.frame_id != sensor_frame) {
    why = "a sun vector is in frame '" + v.header.frame_id + "', not the sensor's '" + sensor_frame + "'";
    return std::nullopt;
  }
  const double norm = std::hypot(v.vector.x, v.vector.y, v.vector.z);
  if (!(norm > 0.0) || !std::isfinite(norm)) {
    why = "a sun vector is zero or not finite";
    return std::nullopt;
  }
  SunAngles t;
  t.header = v.header;
  t.alpha = std::atan2(v.vector.x, v.vector.z);
  t.beta = std::atan2(v.vector.y, v.vector.z);
  t.subfov_class = SunAngles::SUBFOV_UNKNOWN;
  t.valid = v.vector.z > 0.0;
  t.source = "truth";
  return t;
}

geometry_msgs::Vector3Stamped toSunVectorMsg(double alpha_rad, double beta_rad, const std_msgs::Header& header) {
  const Eigen::Vector3d sun = sunVectorFromAngles(alpha_rad, beta_rad);
  geometry_msgs::Vector3Stamped msg;
  msg.header = header;
  msg.vector.x = sun.x();
  msg.vector.y = sun.y();
  msg.vector.z = sun.z();
  return msg;
}

bool insideFieldOfView(const SensorConfig& config, double alpha_rad, double beta_rad) {
  return std::abs(alpha_rad) <= config.fov.alpha_max_deg * kRadPerDeg &&
         std::abs(beta_rad) <= config.fov.beta_max_deg * kRadPerDeg;
}

SunAngles toTruthMsg(const ImageTruth& truth, const SensorConfig& config, const std_msgs::Header& header) {
  SunAngles msg;
  msg.header = header;
  msg.alpha = truth.alpha_rad;
  msg.beta = truth.beta_rad;
  msg.covariance = {0.0, 0.0, 0.0, 0.0};
  msg.subfov_class = truth.subfov_class;
  msg.source = "truth";
  msg.valid = truth.sun.z() > 0.0 && insideFieldOfView(config, truth.alpha_rad, truth.beta_rad);
  if (!msg.valid) msg.status = truth.sun.z() > 0.0 ? status::kOutsideFov : status::kSunBehindSensor;
  return msg;
}

SpotCentres toSpotsMsg(const ImageTruth& truth, const std_msgs::Header& header) {
  SpotCentres msg;
  msg.header = header;
  for (const auto& s : truth.spots) {
    msg.aperture_index.push_back(s.aperture_index);
    msg.x_px.push_back(s.x_px);
    msg.y_px.push_back(s.y_px);
    msg.on_detector.push_back(s.on_detector);
    msg.relative_flux.push_back(s.relative_flux);
  }
  return msg;
}

}  // namespace dss
