// Fits the calibration model to labelled images (detected spots + the true sun
// direction): Levenberg-Marquardt on the geometry (baseline/geometry_fit,
// which says what the data can determine), outlier rejection, then a linear
// least-squares residual polynomial in angle space.
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "digital_sun_sensor/baseline/calibration.h"

namespace dss {

struct CalibrationSample {
  Eigen::Vector3d sun = Eigen::Vector3d::UnitZ();  // true sun direction
  std::vector<DetectedSpot> spots;
};

struct CalibrationFitOptions {
  int polynomial_degree = 3;        // 0: none
  double aperture_prior_um = 20.0;  // per-aperture position prior (gauge fixing)
  double outlier_sigmas = 5.0;      // residuals beyond this many robust sigmas are dropped
  int max_iterations = 100;
};

struct CalibrationFitReport {
  int images = 0;
  int images_used = 0;  // with at least one associated spot
  int observations = 0;
  int outliers = 0;
  int iterations = 0;
  std::vector<std::string> free_parameters;
  double rms_px_design = 0.0;  // spot residual of the design geometry
  double rms_px_fitted = 0.0;
  double angle_rms_deg_geometry = 0.0;  // sun angle error, geometry only (per axis)
  double angle_rms_deg = 0.0;           // with the residual polynomial
  double angle_max_deg = 0.0;

  std::string toYaml() const;  // a YAML map, stored in the calibration file
};

// `calibration` holds the starting point (usually Calibration::nominalOf) and
// receives the fit. Throws CalibrationError when the data cannot support a fit.
CalibrationFitReport fitCalibration(const std::vector<CalibrationSample>& samples, Calibration& calibration,
                                    const CalibrationFitOptions& options = {});

}  // namespace dss
