// Shared by the commands that read dataset bags: the sensor config a bag was
// rendered from, and the check that its images fit a sensor.
#pragma once

#include <optional>
#include <string>

#include "digital_sun_sensor/ros/bag_io.h"

namespace dss::cli {

// The sensor config embedded in a bag's dataset_info, if any.
std::optional<SensorConfig> sensorFromBagInfo(const DatasetBagReader& reader);
// Sensor instances the bag was rendered from (1 when not recorded).
int instancesFromBagInfo(const DatasetBagReader& reader);

// Throws std::runtime_error naming the bag, the image and both sizes when an
// image does not fit the sensor.
void checkImageFitsSensor(const LabelledImage& item, const SensorConfig& config);

// "N pairs; M images without truth, ..." for stderr.
std::string describe(const BagReadStats& stats);

}  // namespace dss::cli
