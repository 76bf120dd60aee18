#include "digital_sun_sensor/baseline/calibration_fit.h"

#include <yaml-cpp/yaml.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>

#include "digital_sun_sensor/baseline/association.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/sim/geometry.h"

namespace dss {
namespace {

enum Global { kHeight, kOffsetX, kOffsetY, kRotation, kTiltX, kTiltY, kNumGlobals };
const char* kGlobalNames[kNumGlobals] = {"height", "offset_x", "offset_y", "rotation", "tilt_x", "tilt_y"};
// Central-difference steps: ~0.01 um of spot motion each.
const double kStep[kNumGlobals] = {0.01, 0.01, 0.01, 1e-7, 1e-7, 1e-7};
constexpr double kApertureStepUm = 0.01;
constexpr double kMeasurementSigmaPx = 0.05;  // scale of the prior against the data

struct Observation {
  int sample;
  SpotObservation spot;
};

// Parameters: the six globals (absolute) then per-aperture (dx, dy) offsets.
MaskGeometry apply(const MaskGeometry& base, const Eigen::VectorXd& p) {
  MaskGeometry g = base;
  g.height_um = p[kHeight];
  g.offset_x_um = p[kOffsetX];
  g.offset_y_um = p[kOffsetY];
  g.rotation_rad = p[kRotation];
  g.tilt_x_rad = p[kTiltX];
  g.tilt_y_rad = p[kTiltY];
  for (int i = 0; i < g.numApertures(); ++i) g.apertures_um[i] += p.segment<2>(kNumGlobals + 2 * i);
  return g;
}

// The geometry field that parameter `index` moves.
double& parameterRef(MaskGeometry& g, int index) {
  switch (index) {
    case kHeight:
      return g.height_um;
    case kOffsetX:
      return g.offset_x_um;
    case kOffsetY:
      return g.offset_y_um;
    case kRotation:
      return g.rotation_rad;
    case kTiltX:
      return g.tilt_x_rad;
    case kTiltY:
      return g.tilt_y_rad;
    default: {
      Eigen::Vector2d& a = g.apertures_um[(index - kNumGlobals) / 2];
      return (index - kNumGlobals) % 2 == 0 ? a.x() : a.y();
    }
  }
}

Eigen::VectorXd initialParameters(const MaskGeometry& g) {
  Eigen::VectorXd p = Eigen::VectorXd::Zero(kNumGlobals + 2 * g.numApertures());
  p[kHeight] = g.height_um;
  p[kOffsetX] = g.offset_x_um;
  p[kOffsetY] = g.offset_y_um;
  p[kRotation] = g.rotation_rad;
  p[kTiltX] = g.tilt_x_rad;
  p[kTiltY] = g.tilt_y_rad;
  return p;
}

// True when three apertures span a triangle (tilt observable).
bool apertureTriangle(const MaskGeometry& g) {
  for (int i = 0; i < g.numApertures(); ++i)
    for (int j = 0; j < i; ++j)
      for (int k = 0; k < j; ++k) {
        const Eigen::Vector2d a = g.apertures_um[j] - g.apertures_um[i], b = g.apertures_um[k] - g.apertures_um[i];
        if (std::abs(a.x() * b.y() - a.y() * b.x()) > 1.0) return true;
      }
  return false;
}

std::vector<Observation> associateAll(const MaskGeometry& g, const std::vector<CalibrationSample>& samples,
                                      double gate_px) {
  std::vector<Observation> out;
  for (int s = 0; s < static_cast<int>(samples.size()); ++s) {
    const Association a = associateWithKnownSun(g, samples[s].spots, samples[s].sun, gate_px);
    for (const auto& o : a.observations) out.push_back({s, o});
  }
  return out;
}

double robustSigma(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return 1.4826 * v[v.size() / 2];
}

class GeometryFit {
 public:
  GeometryFit(const MaskGeometry& base, const std::vector<CalibrationSample>& samples, std::vector<bool> free,
              double prior_weight)
      : base_(base), samples_(samples), free_(std::move(free)), prior_weight_(prior_weight) {}

  double cost(const Eigen::VectorXd& p, const std::vector<Observation>& obs) const {
    const MaskGeometry g = apply(base_, p);
    double sum = prior_weight_ * p.tail(p.size() - kNumGlobals).squaredNorm();
    for (const auto& o : obs) {
      const auto q = g.spotPx(o.spot.aperture, samples_[o.sample].sun);
      sum += q ? (o.spot.measured_px - *q).squaredNorm() : 1e6;
    }
    return sum;
  }

  // Levenberg-Marquardt; returns iterations used.
  int run(Eigen::VectorXd& p, const std::vector<Observation>& obs, int max_iterations) const {
    const int n = static_cast<int>(p.size());
    double current = cost(p, obs), lambda = 1e-4;
    int it = 0;
    for (; it < max_iterations; ++it) {
      Eigen::MatrixXd a = Eigen::MatrixXd::Zero(n, n);
      Eigen::VectorXd b = Eigen::VectorXd::Zero(n);
      MaskGeometry g = apply(base_, p);  // probed in place for the Jacobian
      for (const auto& o : obs) {
        const Eigen::Vector3d& sun = samples_[o.sample].sun;
        const auto q = g.spotPx(o.spot.aperture, sun);
        if (!q) continue;
        const Eigen::Vector2d r = o.spot.measured_px - *q;
        // Sparse row: the globals and this aperture's two offsets.
        int index[kNumGlobals + 2];
        Eigen::Matrix<double, 2, kNumGlobals + 2> jac;
        for (int k = 0; k < kNumGlobals + 2; ++k) {
          index[k] = k < kNumGlobals ? k : kNumGlobals + 2 * o.spot.aperture + (k - kNumGlobals);
          const double step = k < kNumGlobals ? kStep[k] : kApertureStepUm;
          if (!free_[index[k]]) {
            jac.col(k).setZero();
            continue;
          }
          double& field = parameterRef(g, index[k]);
          const double saved = field;
          field = saved + step;
          const auto qp = g.spotPx(o.spot.aperture, sun);
          field = saved - step;
          const auto qm = g.spotPx(o.spot.aperture, sun);
          field = saved;
          jac.col(k) = qp && qm ? Eigen::Vector2d((*qp - *qm) / (2.0 * step)) : Eigen::Vector2d::Zero();
        }
        for (int u = 0; u < kNumGlobals + 2; ++u) {
          b[index[u]] += jac.col(u).dot(r);
          for (int v = 0; v < kNumGlobals + 2; ++v) a(index[u], index[v]) += jac.col(u).dot(jac.col(v));
        }
      }
      for (int k = kNumGlobals; k < n; ++k) {
        a(k, k) += prior_weight_;
        b[k] -= prior_weight_ * p[k];
      }
      for (int k = 0; k < n; ++k)
        if (!free_[k]) a(k, k) = 1.0, b[k] = 0.0;
      bool accepted = false;
      Eigen::VectorXd step;
      for (int attempt = 0; attempt < 10 && !accepted; ++attempt) {
        Eigen::MatrixXd damped = a;
        damped.diagonal() *= 1.0 + lambda;
        step = damped.ldlt().solve(b);
        const double value = cost(p + step, obs);
        if (step.allFinite() && value <= current) {
          p += step;
          current = value;
          lambda = std::max(1e-9, lambda * 0.2);
          accepted = true;
        } else {
          lambda *= 10.0;
        }
      }
      if (!accepted) break;
      double largest = 0.0;  // in units of the step sizes: ~0.01 um of spot motion
      for (int k = 0; k < n; ++k)
        largest = std::max(largest, std::abs(step[k]) / (k < kNumGlobals ? kStep[k] : kApertureStepUm));
      if (largest < 1e-3) break;
    }
    return it + 1;
  }

  std::vector<double> residualNorms(const Eigen::VectorXd& p, const std::vector<Observation>& obs) const {
    const MaskGeometry g = apply(base_, p);
    std::vector<double> out;
    for (const auto& o : obs) {
      const auto q = g.spotPx(o.spot.aperture, samples_[o.sample].sun);
      out.push_back(q ? (o.spot.measured_px - *q).norm() : std::numeric_limits<double>::infinity());
    }
    return out;
  }

 private:
  const MaskGeometry& base_;
  const std::vector<CalibrationSample>& samples_;
  std::vector<bool> free_;
  double prior_weight_;
};

double rms(const std::vector<double>& norms) {
  double s = 0.0;
  int n = 0;
  for (double v : norms)
    if (std::isfinite(v)) s += v * v, ++n;
  return n ? std::sqrt(s / n) : 0.0;
}

}  // namespace

std::string CalibrationFitReport::toYaml() const {
  YAML::Emitter out;
  out << YAML::BeginMap;
  out << YAML::Key << "images" << YAML::Value << images << YAML::Key << "images_used" << YAML::Value << images_used;
  out << YAML::Key << "observations" << YAML::Value << observations << YAML::Key << "outliers" << YAML::Value
      << outliers;
  out << YAML::Key << "iterations" << YAML::Value << iterations;
  out << YAML::Key << "free_parameters" << YAML::Value << YAML::Flow << free_parameters;
  out << YAML::Key << "rms_px_design" << YAML::Value << rms_px_design;
  out << YAML::Key << "rms_px_fitted" << YAML::Value << rms_px_fitted;
  out << YAML::Key << "angle_rms_deg_geometry" << YAML::Value << angle_rms_deg_geometry;
  out << YAML::Key << "angle_rms_deg" << YAML::Value << angle_rms_deg;
  out << YAML::Key << "angle_max_deg" << YAML::Value << angle_max_deg;
  out << YAML::EndMap;
  return out.c_str();
}

CalibrationFitReport fitCalibration(const std::vector<CalibrationSample>& samples, Calibration& calibration,
                                    const CalibrationFitOptions& options) {
  CalibrationFitReport report;
  report.images = static_cast<int>(samples.size());
  const MaskGeometry base = calibration.geometry;
  const int n_ap = base.numApertures();
  if (n_ap == 0) throw CalibrationError("the sensor's mask has no apertures");

  // Which parameters the data can determine (see the header).
  std::vector<bool> free(kNumGlobals + 2 * n_ap, false);
  free[kHeight] = free[kOffsetX] = free[kOffsetY] = true;
  if (n_ap >= 2) {
    free[kRotation] = true;
    std::fill(free.begin() + kNumGlobals, free.end(), true);
  }
  if (apertureTriangle(base)) free[kTiltX] = free[kTiltY] = true;
  for (int k = 0; k < kNumGlobals; ++k)
    if (free[k]) report.free_parameters.push_back(kGlobalNames[k]);
  if (n_ap >= 2) report.free_parameters.push_back("aperture_xy");

  const double prior_px = options.aperture_prior_um / base.pitch_um;
  const double prior_weight = (kMeasurementSigmaPx * kMeasurementSigmaPx) / (prior_px * prior_px);
  GeometryFit fit(base, samples, free, prior_weight);
  const AssociationOptions assoc = AssociationOptions::forSensor(calibration.sensor, base);

  // Associate with the design (wide gate: as-built errors move spots by a few
  // um), fit, then re-associate with the fitted geometry and the normal gate.
  Eigen::VectorXd p = initialParameters(base);
  const double min_spacing_px = base.minApertureSpacingUm() / base.pitch_um;
  std::vector<Observation> obs = associateAll(base, samples, std::min(30.0, 0.4 * min_spacing_px));
  if (obs.size() < 3)
    throw CalibrationError("only " + std::to_string(obs.size()) +
                           " spots could be matched to apertures in the calibration data (need at least 3)");
  report.rms_px_design = rms(fit.residualNorms(p, obs));
  report.iterations += fit.run(p, obs, options.max_iterations);
  obs = associateAll(apply(base, p), samples, assoc.gate_px);

  // How often each aperture's spot is seen when its centre is on the detector
  // (Laplace-smoothed): association weighs a missing spot by it.
  {
    const MaskGeometry fitted = apply(base, p);
    std::vector<int> predicted(n_ap, 0), seen(n_ap, 0);
    std::vector<std::vector<bool>> matched(samples.size(), std::vector<bool>(n_ap, false));
    for (const auto& o : obs) matched[o.sample][o.spot.aperture] = true;
    for (std::size_t s = 0; s < samples.size(); ++s) {
      for (int i = 0; i < n_ap; ++i) {
        const auto q = fitted.spotPx(i, samples[s].sun);
        if (!q || !fitted.insideDetector(*q, assoc.edge_margin_px)) continue;
        ++predicted[i];
        seen[i] += matched[s][i];
      }
    }
    calibration.detection_rate.assign(n_ap, 1.0);
    for (int i = 0; i < n_ap; ++i) calibration.detection_rate[i] = (seen[i] + 1.0) / (predicted[i] + 2.0);
  }

  // Drop outliers (debris-cut or merged spots) and refit.
  const std::vector<double> norms = fit.residualNorms(p, obs);
  const double sigma = robustSigma(norms);
  std::vector<Observation> inliers;
  for (std::size_t k = 0; k < obs.size(); ++k)
    if (norms[k] <= options.outlier_sigmas * sigma + 0.01) inliers.push_back(obs[k]);
  report.outliers = static_cast<int>(obs.size() - inliers.size());
  if (inliers.size() < 3) throw CalibrationError("too few consistent spots in the calibration data");
  report.iterations += fit.run(p, inliers, options.max_iterations);
  report.observations = static_cast<int>(inliers.size());
  const std::vector<double> final_norms = fit.residualNorms(p, inliers);
  report.rms_px_fitted = rms(final_norms);
  calibration.geometry = apply(base, p);
  calibration.centroid_sigma_px = std::max(1e-4, report.rms_px_fitted / std::sqrt(2.0));

  // Residual polynomial on the angle errors of the geometry-only solution.
  std::vector<std::vector<SpotObservation>> per_sample(samples.size());
  for (const auto& o : inliers) per_sample[o.sample].push_back(o.spot);
  struct AngleResidual {
    double alpha, beta, d_alpha, d_beta;
  };
  std::vector<AngleResidual> residuals;
  for (std::size_t s = 0; s < samples.size(); ++s) {
    if (per_sample[s].empty()) continue;
    const SunSolution sol = solveSun(calibration.geometry, per_sample[s]);
    if (!sol.ok) continue;
    const SunAnglesRad truth = anglesFromSunVector(samples[s].sun);
    residuals.push_back({sol.alpha_rad, sol.beta_rad, truth.alpha - sol.alpha_rad, truth.beta - sol.beta_rad});
  }
  report.images_used = static_cast<int>(residuals.size());
  auto& poly = calibration.polynomial;
  poly.degree = 0;
  poly.alpha_coefficients.clear();
  poly.beta_coefficients.clear();
  const int degree = options.polynomial_degree;
  if (degree > 0 && static_cast<int>(residuals.size()) >= 5 * ResidualPolynomial::termCount(degree)) {
    const int terms = ResidualPolynomial::termCount(degree);
    Eigen::MatrixXd a(residuals.size(), terms);
    Eigen::MatrixXd b(residuals.size(), 2);
    for (std::size_t k = 0; k < residuals.size(); ++k) {
      const auto t = ResidualPolynomial::terms(degree, std::tan(residuals[k].alpha) / poly.scale,
                                               std::tan(residuals[k].beta) / poly.scale);
      for (int j = 0; j < terms; ++j) a(k, j) = t[j];
      b(k, 0) = residuals[k].d_alpha;
      b(k, 1) = residuals[k].d_beta;
    }
    const Eigen::MatrixXd coef = a.colPivHouseholderQr().solve(b);
    poly.degree = degree;
    poly.alpha_coefficients.assign(coef.col(0).data(), coef.col(0).data() + terms);
    poly.beta_coefficients.assign(coef.col(1).data(), coef.col(1).data() + terms);
  }
  double sum_geo = 0.0, sum = 0.0;
  for (const auto& r : residuals) {
    const Eigen::Vector2d c = poly.correction(r.alpha, r.beta);
    sum_geo += r.d_alpha * r.d_alpha + r.d_beta * r.d_beta;
    const double ea = r.d_alpha - c.x(), eb = r.d_beta - c.y();
    sum += ea * ea + eb * eb;
    report.angle_max_deg = std::max({report.angle_max_deg, std::abs(ea) / kRadPerDeg, std::abs(eb) / kRadPerDeg});
  }
  if (!residuals.empty()) {
    report.angle_rms_deg_geometry = std::sqrt(sum_geo / (2.0 * residuals.size())) / kRadPerDeg;
    report.angle_rms_deg = std::sqrt(sum / (2.0 * residuals.size())) / kRadPerDeg;
  }
  calibration.fit_yaml = report.toYaml();
  return report;
}

}  // namespace dss
