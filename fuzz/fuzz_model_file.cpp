// Model files as calibration_node and dss read them: the bytes go to a file,
// SscnnEstimator loads it and, when it loads, estimates one image. The first
// byte chooses what the rest is:
//   0: the whole file (the container's own checks: magic, lengths, checksum);
//   1: "<metadata>\0<weights>", packed into a valid container, so the
//      fuzzer reaches the metadata reader and the weights archive;
//   2: a replacement for one section (next byte) of a valid small model.
#include <unistd.h>

#include <cstdio>
#include <opencv2/core.hpp>

#include "digital_sun_sensor/common/container.h"
#include "digital_sun_sensor/common/file_io.h"
#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/model/sscnn_estimator.h"
#include "digital_sun_sensor/sim/sensor_config.h"
#include "fuzz_entry.h"

namespace {

const dss::SensorConfig& sensor() {
  static const dss::SensorConfig config =
      dss::loadSensorConfig(dss::fuzz::sourceDir() + "/config/sensors/thesis_sa.yaml");
  return config;
}

// The sections of a freshly created small model (metadata, weights).
const dss::Container& validModel() {
  static const dss::Container model = dss::unpackContainer(
      dss::serializeModel(dss::createModel(sensor(), "resnet10_w16")), "DSSMODEL", "model", "valid model");
  return model;
}

}  // namespace

extern "C" int DSS_FUZZ_ENTRY(const std::uint8_t* data, std::size_t size) {
  if (size < 1) return 0;
  std::string bytes;
  const int mode = data[0] % 3;
  if (mode == 0) {
    bytes.assign(reinterpret_cast<const char*>(data + 1), size - 1);
  } else if (mode == 1) {
    auto parts = dss::fuzz::splitAtNul(data + 1, size - 1, 2);
    parts.resize(2);
    bytes = dss::packContainer("DSSMODEL", 2, parts);
  } else {
    if (size < 2) return 0;
    std::vector<std::string> sections = validModel().sections;
    sections[data[1] % 2].assign(reinterpret_cast<const char*>(data + 2), size - 2);
    bytes = dss::packContainer("DSSMODEL", 2, sections);
  }
  const std::string path = "/tmp/dss_fuzz_model." + std::to_string(::getpid()) + ".dssmodel";
  dss::writeFileAtomic(path, bytes);
  try {
    dss::SscnnEstimator estimator(path, &sensor());
    cv::Mat image = cv::Mat::zeros(sensor().detector.height_px, sensor().detector.width_px, CV_8UC1);
    image(cv::Rect(250, 250, 12, 12)).setTo(200);
    try {
      estimator.estimate({image});
    } catch (const std::exception&) {
      // calibration_node answers estimator_error for the image; not a crash
    }
  } catch (const dss::ModelError&) {
  }
  std::remove(path.c_str());
  return 0;
}
