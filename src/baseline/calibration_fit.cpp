#include "digital_sun_sensor/baseline/calibration_fit.h"

#include <yaml-cpp/yaml.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>

#include "digital_sun_sensor/baseline/association.h"
#include "digital_sun_sensor/baseline/geometry_fit.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/sim/geometry.h"

namespace dss {
namespace {

constexpr double kMeasurementSigmaPx = 0.05;  // scale of the prior against the data

std::vector<GeometryObservation> associateAll(const MaskGeometry& g, const std::vector<CalibrationSample>& samples,
                                              double gate_px) {
  std::vector<GeometryObservation> out;
  for (int s = 0; s < static_cast<int>(samples.size()); ++s) {
    const Association a = associateWithKnownSun(g, samples[s].spots, samples[s].sun, gate_px);
    for (const auto& o : a.observations) {
      GeometryObservation obs;
      obs.sample = s;
      obs.sun = samples[s].sun;
      obs.apertures = {o.aperture};
      obs.measured_px = o.measured_px;
      out.push_back(obs);
    }
  }
  return out;
}

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

  const double prior_px = options.aperture_prior_um / base.pitch_um;
  const double prior_weight = (kMeasurementSigmaPx * kMeasurementSigmaPx) / (prior_px * prior_px);
  const GeometryFit fit(base, prior_weight);
  report.free_parameters = fit.freeParameters();
  const AssociationOptions assoc = AssociationOptions::forSensor(calibration.sensor, base);

  // Associate with the design (wide gate: as-built errors move spots by a few
  // um), fit, then re-associate with the fitted geometry and the normal gate.
  Eigen::VectorXd p = fit.start();
  const double min_spacing_px = base.minApertureSpacingUm() / base.pitch_um;
  std::vector<GeometryObservation> obs = associateAll(base, samples, std::min(30.0, 0.4 * min_spacing_px));
  if (obs.size() < 3)
    throw CalibrationError("only " + std::to_string(obs.size()) +
                           " spots could be matched to apertures in the calibration data (need at least 3)");
  report.rms_px_design = rms(fit.residualNorms(p, obs));
  report.iterations += fit.run(p, obs, options.max_iterations);
  obs = associateAll(fit.apply(p), samples, assoc.gate_px);

  // How often each aperture's spot is seen when its centre is on the detector
  // (Laplace-smoothed): association weighs a missing spot by it.
  {
    const MaskGeometry fitted = fit.apply(p);
    std::vector<int> predicted(n_ap, 0), seen(n_ap, 0);
    std::vector<std::vector<bool>> matched(samples.size(), std::vector<bool>(n_ap, false));
    for (const auto& o : obs) matched[o.sample][o.apertures.front()] = true;
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
  std::vector<GeometryObservation> inliers;
  for (std::size_t k = 0; k < obs.size(); ++k)
    if (norms[k] <= options.outlier_sigmas * sigma + 0.01) inliers.push_back(obs[k]);
  report.outliers = static_cast<int>(obs.size() - inliers.size());
  if (inliers.size() < 3) throw CalibrationError("too few consistent spots in the calibration data");
  report.iterations += fit.run(p, inliers, options.max_iterations);
  report.observations = static_cast<int>(inliers.size());
  const std::vector<double> final_norms = fit.residualNorms(p, inliers);
  report.rms_px_fitted = rms(final_norms);
  calibration.geometry = fit.apply(p);
  calibration.centroid_sigma_px = std::max(1e-4, report.rms_px_fitted / std::sqrt(2.0));

  // Residual polynomial on the angle errors of the geometry-only solution.
  std::vector<std::vector<SpotObservation>> per_sample(samples.size());
  for (const auto& o : inliers) per_sample[o.sample].push_back({o.apertures.front(), o.measured_px});
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
