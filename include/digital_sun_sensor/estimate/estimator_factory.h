// Builds the sun estimators the front ends name (dss eval, calibration_node):
// the SSCNN from a model file, the centroid baseline from a calibration file,
// and the estimator node's choice of one with the other as fallback.
// Torch-free header.
#pragma once

#include <memory>
#include <string>

#include "digital_sun_sensor/common/sun_estimate.h"

namespace dss {

struct EstimatorOptions {
  // Average the SSCNN's estimates over the mirror images its model file names
  // (inference_symmetry, model/symmetry). false: the image alone, 4 to 8 times
  // less inference, a little less accurate; its sigma stays the one that was
  // calibrated for the average.
  bool mirror_average = true;
};

// The front ends' "inference_symmetry" setting: "model" (mirror_average) or
// "none". Throws std::invalid_argument naming the value otherwise.
bool mirrorAverageFromName(const std::string& name);

// "sscnn:MODEL", "centroid:CALIB" or "pattern:SENSOR_CONFIG" (the whole-pattern
// solve of a mask whose spots merge). Throws std::invalid_argument for a
// malformed spec, ModelError / CalibrationError for a bad file; with
// `expected`, also when the file was made for another sensor design.
std::unique_ptr<SunEstimator> makeEstimator(const std::string& spec, const SensorConfig* expected = nullptr,
                                            const EstimatorOptions& options = {});

struct EstimatorChoice {
  std::unique_ptr<SunEstimator> estimator;  // null when neither file could be used
  bool is_fallback = false;                 // the baseline (centroid or pattern) stands in for the SSCNN
  std::string problem;                      // why the SSCNN (and the fallback) was not used; empty if it was
};

// The calibration path that names the whole-pattern estimator of the sensor
// (baseline/pattern_estimator.h) as the fallback: no file, the design itself.
constexpr const char* kPatternFallback = "pattern";

// The SSCNN from `model_path` when it loads and fits `sensor`; otherwise the
// centroid baseline from `calibration_path` (when not empty; kPatternFallback:
// the whole-pattern estimator). Never throws for a missing or bad file: the
// reason is in `problem`.
EstimatorChoice chooseEstimator(const std::string& model_path, const std::string& calibration_path,
                                const SensorConfig& sensor, const EstimatorOptions& options = {});

}  // namespace dss
