// sensor_msgs/Image fields as calibration_node receives them, through the
// node's own path: the image copy, then the estimator the node runs (the
// SSCNN of a small model, or the centroid baseline of the shipped
// calibration, screened as in the node). Input layout (little-endian):
//   u8 flags (bit 0: SSCNN, bit 1: big-endian), u32 width, u32 height,
//   u32 step, u8 encoding length, the encoding, then the data.
#include <cstring>

#include "digital_sun_sensor/common/estimate_status.h"
#include "digital_sun_sensor/estimate/estimator_factory.h"
#include "digital_sun_sensor/estimate/screened_estimator.h"
#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/ros/conversions.h"
#include "digital_sun_sensor/sim/sensor_config.h"
#include "fuzz_entry.h"

namespace {

struct Estimators {
  dss::SensorConfig sensor;
  std::unique_ptr<dss::SunEstimator> sscnn, centroid;
  Estimators() {
    sensor = dss::loadSensorConfig(dss::fuzz::sourceDir() + "/config/sensors/thesis_sa.yaml");
    const std::string model_path = "/tmp/dss_fuzz_image_msg.dssmodel";
    dss::saveModel(dss::createModel(sensor, "resnet10_w16"), model_path);
    sscnn = std::make_unique<dss::ScreenedEstimator>(dss::chooseEstimator(model_path, "", sensor).estimator,
                                                     dss::ScreenOptions{});
    centroid = std::make_unique<dss::ScreenedEstimator>(
        dss::chooseEstimator("", dss::fuzz::sourceDir() + "/models/thesis_sa.calib.yaml", sensor).estimator,
        dss::ScreenOptions{});
  }
};

Estimators estimators;  // before the fuzzer starts (see fuzz_checkpoint.cpp)

}  // namespace

extern "C" int DSS_FUZZ_ENTRY(const std::uint8_t* data, std::size_t size) {
  if (size < 14) return 0;
  sensor_msgs::Image msg;
  std::memcpy(&msg.width, data + 1, 4);
  std::memcpy(&msg.height, data + 5, 4);
  std::memcpy(&msg.step, data + 9, 4);
  msg.is_bigendian = (data[0] >> 1) & 1;
  const std::size_t encoding_bytes = std::min<std::size_t>(data[13], size - 14);
  msg.encoding.assign(reinterpret_cast<const char*>(data + 14), encoding_bytes);
  msg.data.assign(data + 14 + encoding_bytes, data + size);
  cv::Mat image;
  try {
    image = dss::imageFromMsg(msg);
  } catch (const std::invalid_argument&) {
    return 0;  // the node answers bad_image
  }
  dss::SunEstimator& estimator = (data[0] & 1) ? *estimators.sscnn : *estimators.centroid;
  try {
    estimator.estimate({image});
  } catch (const std::exception&) {
    // the node answers estimator_error for the image
  }
  return 0;
}
