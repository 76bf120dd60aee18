#include "digital_sun_sensor/baseline/calibration_model.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>

#include "digital_sun_sensor/sim/geometry.h"
#include "digital_sun_sensor/sim/sensor_instance.h"

namespace dss {

MaskGeometry MaskGeometry::nominalOf(const SensorConfig& config) {
  MaskGeometry g;
  g.pitch_um = config.detector.pitch_um;
  g.width_px = config.detector.width_px;
  g.height_px = config.detector.height_px;
  g.height_um = config.mask.height_mm * 1000.0;
  if (config.cover_glass.enabled) {
    g.glass_thickness_um = config.cover_glass.thickness_mm * 1000.0;
    g.glass_index = config.cover_glass.refractive_index;
  }
  for (const auto& a : config.mask.apertures) {
    g.apertures_um.emplace_back(a.x_um, a.y_um);
    g.aperture_diameters_um.push_back(a.shape == ApertureShape::kCircle ? a.diameter_um
                                                                        : std::sqrt(a.width_um * a.height_um));
  }
  return g;
}

double MaskGeometry::minApertureSpacingUm() const {
  double spacing = std::numeric_limits<double>::infinity();
  for (int i = 0; i < numApertures(); ++i)
    for (int j = 0; j < i; ++j) spacing = std::min(spacing, (apertures_um[i] - apertures_um[j]).norm());
  return spacing;
}

Eigen::Vector3d MaskGeometry::apertureCentreUm(int i) const {
  const Eigen::Vector2d& a = apertures_um.at(i);
  return maskRotation(rotation_rad, tilt_x_rad, tilt_y_rad) * Eigen::Vector3d(a.x(), a.y(), 0.0) +
         Eigen::Vector3d(offset_x_um, offset_y_um, height_um);
}

std::optional<Eigen::Vector2d> MaskGeometry::spotPx(int i, const Eigen::Vector3d& sun) const {
  const Eigen::Vector3d centre = apertureCentreUm(i);
  const double glass_um = std::max(0.0, std::min(glass_thickness_um, centre.z() - air_above_exit_um));
  const auto hit = traceToDetector(centre, sun, GlassSlab{glass_um, glass_index});
  if (!hit) return std::nullopt;
  return Eigen::Vector2d(*hit / pitch_um);
}

int subFovClassOf(SubFovType type, const MaskGeometry& geometry, double alpha_rad, double beta_rad) {
  if (type == SubFovType::kQuadrant) return quadrantClass(alpha_rad, beta_rad);
  const Eigen::Vector3d sun = sunVectorFromAngles(alpha_rad, beta_rad);
  int nearest = -1;
  double best = std::numeric_limits<double>::max();
  for (int i = 0; i < geometry.numApertures(); ++i) {
    const auto p = geometry.spotPx(i, sun);
    if (p && p->squaredNorm() < best) best = p->squaredNorm(), nearest = i;
  }
  return nearest;
}

bool MaskGeometry::insideDetector(const Eigen::Vector2d& spot_px, double margin_px) const {
  return std::abs(spot_px.x()) < 0.5 * width_px - margin_px && std::abs(spot_px.y()) < 0.5 * height_px - margin_px;
}

std::vector<double> ResidualPolynomial::terms(int degree, double u, double v) {
  std::vector<double> out;
  out.reserve(termCount(degree));
  for (int total = 0; total <= degree; ++total)
    for (int j = 0; j <= total; ++j) out.push_back(std::pow(u, total - j) * std::pow(v, j));
  return out;
}

Eigen::Vector2d ResidualPolynomial::correction(double alpha_rad, double beta_rad) const {
  if (degree <= 0 || alpha_coefficients.empty()) return Eigen::Vector2d::Zero();
  const auto t = terms(degree, std::tan(alpha_rad) / scale, std::tan(beta_rad) / scale);
  Eigen::Vector2d c = Eigen::Vector2d::Zero();
  for (std::size_t k = 0; k < t.size() && k < alpha_coefficients.size(); ++k) {
    c.x() += alpha_coefficients[k] * t[k];
    c.y() += beta_coefficients[k] * t[k];
  }
  return c;
}

SunSolution solveSun(const MaskGeometry& geometry, const std::vector<SpotObservation>& observations) {
  SunSolution out;
  if (observations.empty()) return out;
  // Paraxial start: the spot moves by -h_eff tan(angle), glass shortening h.
  const auto& first = observations.front();
  const Eigen::Vector3d ap = geometry.apertureCentreUm(first.aperture);
  const double glass = std::min(geometry.glass_thickness_um, ap.z());
  const double h_eff = ap.z() - glass + glass / geometry.glass_index;
  double alpha = std::atan(-(first.measured_px.x() * geometry.pitch_um - ap.x()) / h_eff);
  double beta = std::atan(-(first.measured_px.y() * geometry.pitch_um - ap.y()) / h_eff);
  alpha = std::clamp(alpha, -1.5, 1.5);
  beta = std::clamp(beta, -1.5, 1.5);

  const int n = static_cast<int>(observations.size());
  auto residuals = [&](double a, double b, Eigen::VectorXd& r) {
    r.resize(2 * n);
    const Eigen::Vector3d sun = sunVectorFromAngles(a, b);
    for (int k = 0; k < n; ++k) {
      const auto p = geometry.spotPx(observations[k].aperture, sun);
      if (!p) return false;
      r.segment<2>(2 * k) = observations[k].measured_px - *p;
    }
    return true;
  };
  Eigen::VectorXd r, rp, rm;
  Eigen::MatrixXd jac(2 * n, 2);
  constexpr double kStep = 1e-7;
  double lambda = 1e-6;
  if (!residuals(alpha, beta, r)) return out;
  for (int it = 0; it < 30; ++it) {
    for (int axis = 0; axis < 2; ++axis) {
      const double da = axis == 0 ? kStep : 0.0, db = axis == 1 ? kStep : 0.0;
      if (!residuals(alpha + da, beta + db, rp) || !residuals(alpha - da, beta - db, rm)) return out;
      jac.col(axis) = -(rp - rm) / (2.0 * kStep);  // d(predicted)/d(angle)
    }
    const Eigen::Matrix2d jtj = jac.transpose() * jac;
    const Eigen::Vector2d jtr = jac.transpose() * r;
    Eigen::Matrix2d damped = jtj;
    damped.diagonal() *= 1.0 + lambda;
    const Eigen::Vector2d step = damped.ldlt().solve(jtr);
    Eigen::VectorXd r_new;
    if (!step.allFinite() || !residuals(alpha + step.x(), beta + step.y(), r_new) ||
        r_new.squaredNorm() > r.squaredNorm() * (1.0 + 1e-12)) {
      lambda *= 100.0;
      if (lambda > 1e6) break;
      continue;
    }
    alpha += step.x();
    beta += step.y();
    r = r_new;
    lambda = std::max(1e-9, lambda * 0.1);
    if (step.norm() < 1e-12) break;
  }
  for (int axis = 0; axis < 2; ++axis) {
    const double da = axis == 0 ? kStep : 0.0, db = axis == 1 ? kStep : 0.0;
    if (!residuals(alpha + da, beta + db, rp) || !residuals(alpha - da, beta - db, rm)) return out;
    jac.col(axis) = -(rp - rm) / (2.0 * kStep);
  }
  out.alpha_rad = alpha;
  out.beta_rad = beta;
  out.normal_matrix = jac.transpose() * jac;
  out.rms_px = std::sqrt(r.squaredNorm() / n);
  out.ok = std::isfinite(alpha) && std::isfinite(beta) && std::abs(alpha) < M_PI_2 && std::abs(beta) < M_PI_2;
  return out;
}

}  // namespace dss
