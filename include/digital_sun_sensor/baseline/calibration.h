// A fitted conventional calibration (the baseline's CALIB.yaml): the sensor
// design it belongs to, spot extraction settings, the fitted geometry, the
// residual polynomial and the centroid noise seen in the fit.
#pragma once

#include <stdexcept>
#include <string>

#include "digital_sun_sensor/baseline/calibration_model.h"
#include "digital_sun_sensor/baseline/spot_extraction.h"

namespace dss {

class CalibrationError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct Calibration {
  SensorConfig sensor;
  SpotExtractionConfig extraction;
  MaskGeometry geometry;
  ResidualPolynomial polynomial;
  double centroid_sigma_px = 0.05;  // per axis, robust scatter of the fit residuals
  // Per aperture: fraction of calibration images in which its spot was seen
  // while its centre was on the detector (empty: not measured).
  std::vector<double> detection_rate;
  std::string fit_yaml = "{}";  // fit statistics and provenance (a YAML map)

  // The design itself, before any fit.
  static Calibration nominalOf(const SensorConfig& config);
};

std::string toYaml(const Calibration& calibration);
// Throws CalibrationError naming `origin` and the problem.
Calibration parseCalibration(const std::string& yaml_text, const std::string& origin);
Calibration loadCalibration(const std::string& path);
void saveCalibration(const std::string& path, const Calibration& calibration);  // atomic

}  // namespace dss
