#include "digital_sun_sensor/estimate/estimator_factory.h"

#include <stdexcept>

#include "digital_sun_sensor/baseline/calibration.h"
#include "digital_sun_sensor/baseline/centroid_estimator.h"
#include "digital_sun_sensor/baseline/pattern_estimator.h"
#include "digital_sun_sensor/model/sscnn_estimator.h"

namespace dss {
namespace {

std::unique_ptr<SunEstimator> makeCentroid(const std::string& path, const SensorConfig* expected) {
  Calibration calibration = loadCalibration(path);
  if (expected) {
    const std::string mismatch = sensorDesignMismatch(calibration.sensor, *expected);
    if (!mismatch.empty()) throw CalibrationError(path + ": the calibration was made for " + mismatch);
  }
  return std::make_unique<CentroidEstimator>(std::move(calibration));
}

}  // namespace

bool mirrorAverageFromName(const std::string& name) {
  if (name == "model") return true;
  if (name == "none") return false;
  throw std::invalid_argument(
      "inference symmetry must be 'model' (the model file's) or 'none' (the image alone), got '" + name + "'");
}

std::unique_ptr<SunEstimator> makeEstimator(const std::string& spec, const SensorConfig* expected,
                                            const EstimatorOptions& options) {
  const auto colon = spec.find(':');
  const std::string kind = spec.substr(0, colon), path = colon == std::string::npos ? "" : spec.substr(colon + 1);
  if (path.empty() || (kind != "centroid" && kind != "sscnn" && kind != "pattern"))
    throw std::invalid_argument("estimator must be sscnn:MODEL, centroid:CALIB or pattern:SENSOR_CONFIG, got '" + spec +
                                "'");
  if (kind == "centroid") return makeCentroid(path, expected);
  if (kind == "pattern") {
    const SensorConfig config = loadSensorConfig(path);
    if (expected) {
      const std::string mismatch = sensorDesignMismatch(config, *expected);
      if (!mismatch.empty()) throw std::invalid_argument(path + ": the sensor config describes " + mismatch);
    }
    return std::make_unique<PatternEstimator>(config);
  }
  return std::make_unique<SscnnEstimator>(path, expected, options.mirror_average);
}

EstimatorChoice chooseEstimator(const std::string& model_path, const std::string& calibration_path,
                                const SensorConfig& sensor, const EstimatorOptions& options) {
  EstimatorChoice choice;
  if (model_path.empty()) {
    choice.problem = "no model file given";
  } else {
    try {
      choice.estimator = std::make_unique<SscnnEstimator>(model_path, &sensor, options.mirror_average);
      return choice;
    } catch (const std::exception& e) {
      choice.problem = e.what();
    }
  }
  if (calibration_path.empty()) {
    choice.problem += "; no calibration file for the centroid fallback";
    return choice;
  }
  try {
    if (calibration_path == kPatternFallback)
      choice.estimator = std::make_unique<PatternEstimator>(sensor);
    else
      choice.estimator = makeCentroid(calibration_path, &sensor);
    choice.is_fallback = true;
  } catch (const std::exception& e) {
    choice.problem += std::string("; ") + (calibration_path == kPatternFallback ? "pattern" : "centroid") +
                      " fallback failed too: " + e.what();
  }
  return choice;
}

}  // namespace dss
