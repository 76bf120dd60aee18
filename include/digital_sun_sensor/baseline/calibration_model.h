// The conventional calibration model: pinhole geometry (mask height, offset,
// rotation, tilt, per-aperture positions) with exact cover-glass refraction,
// mapping a sun vector to each aperture's spot centre on the detector, and a
// low-order polynomial correcting what the geometry leaves in angle space.
#pragma once

#include <Eigen/Core>
#include <optional>
#include <utility>
#include <vector>

#include "digital_sun_sensor/sim/sensor_config.h"

namespace dss {

struct MaskGeometry {
  double pitch_um = 1.55;
  int width_px = 512;
  int height_px = 512;
  // Detector surface to the mask's exit face. Fitted, it also absorbs half the
  // mask thickness: vignetting at oblique incidence moves the transmitted
  // beam's centre by thickness/2 x tan(angle).
  double height_um = 5000.0;
  double offset_x_um = 0.0;
  double offset_y_um = 0.0;
  double rotation_rad = 0.0;  // about the boresight
  double tilt_x_rad = 0.0;
  double tilt_y_rad = 0.0;
  double glass_thickness_um = 0.0;  // cover glass on the detector (0: none)
  double glass_index = 1.0;
  // The part of the height above the mask's exit face, always in air (the
  // geometric head's height is the mid-plane, t / 2 above the exit face: a
  // mask lowered into a thinner glass keeps it above the glass). 0: the
  // baseline's fitted height, which absorbs it.
  double air_above_exit_um = 0.0;
  std::vector<Eigen::Vector2d> apertures_um;  // centres in the mask frame
  std::vector<double> aperture_diameters_um;  // design values (association by spot size)

  // The design as drawn in a sensor config.
  static MaskGeometry nominalOf(const SensorConfig& config);

  int numApertures() const { return static_cast<int>(apertures_um.size()); }
  // Smallest distance between two aperture centres (infinity for one aperture).
  double minApertureSpacingUm() const;
  // Aperture centre (exit face) in the sensor frame [um].
  Eigen::Vector3d apertureCentreUm(int i) const;
  // Spot centre of aperture i [px from the detector centre], or nullopt when
  // the sun is at or below the mask plane.
  std::optional<Eigen::Vector2d> spotPx(int i, const Eigen::Vector3d& sun) const;
  // True when a spot centre lies at least `margin_px` inside the detector.
  bool insideDetector(const Eigen::Vector2d& spot_px, double margin_px = 0.0) const;
};

// Sum of c_k u^i v^j over i + j <= degree, (u, v) = (tan alpha, tan beta) / scale.
struct ResidualPolynomial {
  int degree = 0;  // 0: no correction
  double scale = 1.0;
  std::vector<double> alpha_coefficients;  // [rad], one per term
  std::vector<double> beta_coefficients;

  static int termCount(int degree) { return (degree + 1) * (degree + 2) / 2; }
  static std::vector<double> terms(int degree, double u, double v);
  // Correction to add to (alpha, beta) estimated by the geometry.
  Eigen::Vector2d correction(double alpha_rad, double beta_rad) const;
};

// One spot assigned to one aperture.
struct SpotObservation {
  int aperture = 0;
  Eigen::Vector2d measured_px;
};

struct SunSolution {
  double alpha_rad = 0.0;
  double beta_rad = 0.0;
  Eigen::Matrix2d normal_matrix = Eigen::Matrix2d::Zero();  // J^T J, J = d(spots px)/d(alpha, beta)
  double rms_px = 0.0;                                      // residual of the observations
  bool ok = false;
};

// Least-squares sun angles from observed spots (Gauss-Newton on alpha, beta),
// started from the paraxial inversion of the first observation.
SunSolution solveSun(const MaskGeometry& geometry, const std::vector<SpotObservation>& observations);

// The sub-FOV class of estimated angles: the quadrant, or the aperture
// whose spot the geometry puts nearest the detector centre (-1: none).
int subFovClassOf(SubFovType type, const MaskGeometry& geometry, double alpha_rad, double beta_rad);

}  // namespace dss
