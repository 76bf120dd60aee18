#include "digital_sun_sensor/baseline/geometry_fit.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

namespace dss {
namespace {

enum Global { kHeight, kOffsetX, kOffsetY, kRotation, kTiltX, kTiltY, kNumGlobals };
const char* kGlobalNames[kNumGlobals] = {"height", "offset_x", "offset_y", "rotation", "tilt_x", "tilt_y"};
// Central-difference steps: ~0.01 um of spot motion each.
const double kStep[kNumGlobals] = {0.01, 0.01, 0.01, 1e-7, 1e-7, 1e-7};
constexpr double kApertureStepUm = 0.01;

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
      Eigen::Vector2d& a = g.apertures_um[static_cast<std::size_t>((index - kNumGlobals) / 2)];
      return (index - kNumGlobals) % 2 == 0 ? a.x() : a.y();
    }
  }
}

// True when three apertures span a triangle (tilt observable).
bool apertureTriangle(const MaskGeometry& g) {
  for (std::size_t i = 0; i < g.apertures_um.size(); ++i)
    for (std::size_t j = 0; j < i; ++j)
      for (std::size_t k = 0; k < j; ++k) {
        const Eigen::Vector2d a = g.apertures_um[j] - g.apertures_um[i], b = g.apertures_um[k] - g.apertures_um[i];
        if (std::abs(a.x() * b.y() - a.y() * b.x()) > 1.0) return true;
      }
  return false;
}

}  // namespace

GeometryFit::GeometryFit(const MaskGeometry& base, double prior_weight,
                         const std::vector<double>& aperture_prior_weights)
    : base_(base), prior_weights_(static_cast<std::size_t>(base.numApertures()), prior_weight) {
  const int n_ap = base.numApertures();
  if (!aperture_prior_weights.empty()) {
    if (aperture_prior_weights.size() != prior_weights_.size())
      throw std::invalid_argument("geometry fit: " + std::to_string(aperture_prior_weights.size()) +
                                  " aperture prior weights for " + std::to_string(n_ap) + " apertures");
    prior_weights_ = aperture_prior_weights;
  }
  free_.assign(static_cast<std::size_t>(kNumGlobals + 2 * n_ap), false);
  free_[kHeight] = free_[kOffsetX] = free_[kOffsetY] = true;
  if (n_ap >= 2) {
    free_[kRotation] = true;
    std::fill(free_.begin() + kNumGlobals, free_.end(), true);
  }
  if (apertureTriangle(base)) free_[kTiltX] = free_[kTiltY] = true;
}

Eigen::VectorXd GeometryFit::start() const {
  Eigen::VectorXd p = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(free_.size()));
  MaskGeometry g = base_;
  for (int k = 0; k < kNumGlobals; ++k) p[k] = parameterRef(g, k);
  return p;
}

MaskGeometry GeometryFit::apply(const Eigen::VectorXd& p) const {
  MaskGeometry g = base_;
  for (int k = 0; k < kNumGlobals; ++k) parameterRef(g, k) = p[k];
  for (std::size_t i = 0; i < g.apertures_um.size(); ++i)
    g.apertures_um[i] += p.segment<2>(kNumGlobals + 2 * static_cast<Eigen::Index>(i));
  return g;
}

std::vector<std::string> GeometryFit::freeParameters() const {
  std::vector<std::string> names;
  for (int k = 0; k < kNumGlobals; ++k)
    if (free_[static_cast<std::size_t>(k)]) names.emplace_back(kGlobalNames[k]);
  if (free_.size() > kNumGlobals && free_[kNumGlobals]) names.emplace_back("aperture_xy");
  return names;
}

bool GeometryFit::predict(const MaskGeometry& g, const GeometryObservation& o, Eigen::Vector2d& spot_px) const {
  if (o.apertures.size() == 1) {
    const auto q = g.spotPx(o.apertures.front(), o.sun);
    if (q) spot_px = *q;
    return q.has_value();
  }
  Eigen::Vector2d sum = Eigen::Vector2d::Zero();
  double flux = 0.0;
  for (std::size_t m = 0; m < o.apertures.size(); ++m) {
    const auto q = g.spotPx(o.apertures[m], o.sun);
    if (!q) return false;
    sum += o.fluxes[m] * *q;
    flux += o.fluxes[m];
  }
  spot_px = sum / flux;
  return flux > 0.0;
}

double GeometryFit::cost(const Eigen::VectorXd& p, const std::vector<GeometryObservation>& obs) const {
  const MaskGeometry g = apply(p);
  double sum = 0.0;
  for (std::size_t k = 0; k < prior_weights_.size(); ++k)
    sum += prior_weights_[k] * p.segment<2>(kNumGlobals + 2 * static_cast<Eigen::Index>(k)).squaredNorm();
  Eigen::Vector2d q;
  for (const auto& o : obs) sum += predict(g, o, q) ? o.weight * (o.measured_px - q).squaredNorm() : 1e6;
  return sum;
}

void GeometryFit::normalEquations(const Eigen::VectorXd& p, const std::vector<GeometryObservation>& obs,
                                  Eigen::MatrixXd& a, Eigen::VectorXd& b) const {
  const auto n = static_cast<Eigen::Index>(p.size());
  a = Eigen::MatrixXd::Zero(n, n);
  b = Eigen::VectorXd::Zero(n);
  MaskGeometry g = apply(p);  // probed in place for the Jacobian
  Eigen::Vector2d q, qp, qm;
  std::vector<int> index;
  for (const auto& o : obs) {
    if (!predict(g, o, q)) continue;
    const Eigen::Vector2d r = o.measured_px - q;
    // Sparse row: the globals and the offsets of this spot's apertures.
    index.clear();
    for (int k = 0; k < kNumGlobals; ++k) index.push_back(k);
    for (int aperture : o.apertures)
      for (int axis = 0; axis < 2; ++axis) index.push_back(kNumGlobals + 2 * aperture + axis);
    Eigen::Matrix<double, 2, Eigen::Dynamic> jac(2, static_cast<Eigen::Index>(index.size()));
    for (std::size_t k = 0; k < index.size(); ++k) {
      const auto col = static_cast<Eigen::Index>(k);
      const double step = index[k] < kNumGlobals ? kStep[index[k]] : kApertureStepUm;
      if (!free_[static_cast<std::size_t>(index[k])]) {
        jac.col(col).setZero();
        continue;
      }
      double& field = parameterRef(g, index[k]);
      const double saved = field;
      field = saved + step;
      const bool plus = predict(g, o, qp);
      field = saved - step;
      const bool minus = predict(g, o, qm);
      field = saved;
      jac.col(col) = plus && minus ? Eigen::Vector2d((qp - qm) / (2.0 * step)) : Eigen::Vector2d::Zero();
    }
    for (std::size_t u = 0; u < index.size(); ++u) {
      const auto cu = static_cast<Eigen::Index>(u);
      b[index[u]] += o.weight * jac.col(cu).dot(r);
      for (std::size_t v = 0; v < index.size(); ++v)
        a(index[u], index[v]) += o.weight * jac.col(cu).dot(jac.col(static_cast<Eigen::Index>(v)));
    }
  }
  for (Eigen::Index k = kNumGlobals; k < n; ++k) {
    const double prior = prior_weights_[static_cast<std::size_t>((k - kNumGlobals) / 2)];
    a(k, k) += prior;
    b[k] -= prior * p[k];
  }
  for (Eigen::Index k = 0; k < n; ++k)
    if (!free_[static_cast<std::size_t>(k)]) a(k, k) = 1.0, b[k] = 0.0;
}

int GeometryFit::run(Eigen::VectorXd& p, const std::vector<GeometryObservation>& obs, int max_iterations) const {
  const auto n = static_cast<Eigen::Index>(p.size());
  double current = cost(p, obs), lambda = 1e-4;
  int it = 0;
  Eigen::MatrixXd a;
  Eigen::VectorXd b;
  for (; it < max_iterations; ++it) {
    normalEquations(p, obs, a, b);
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
    for (Eigen::Index k = 0; k < n; ++k)
      largest = std::max(largest, std::abs(step[k]) / (k < kNumGlobals ? kStep[k] : kApertureStepUm));
    if (largest < 1e-3) break;
  }
  return it + 1;
}

double GeometryFit::residualVariance(const Eigen::VectorXd& p, const std::vector<GeometryObservation>& obs) const {
  const MaskGeometry g = apply(p);
  double chi2 = 0.0;
  Eigen::Vector2d q;
  for (const auto& o : obs)
    if (predict(g, o, q)) chi2 += o.weight * (o.measured_px - q).squaredNorm();
  const auto free = static_cast<double>(std::count(free_.begin(), free_.end(), true));
  return chi2 / std::max(1.0, 2.0 * static_cast<double>(obs.size()) - free);
}

Eigen::MatrixXd GeometryFit::covariance(const Eigen::VectorXd& p, const std::vector<GeometryObservation>& obs) const {
  Eigen::MatrixXd a;
  Eigen::VectorXd b;
  normalEquations(p, obs, a, b);
  Eigen::MatrixXd out = a.ldlt().solve(Eigen::MatrixXd::Identity(a.rows(), a.cols())) * residualVariance(p, obs);
  for (Eigen::Index k = 0; k < out.rows(); ++k)
    if (!free_[static_cast<std::size_t>(k)]) out.row(k).setZero(), out.col(k).setZero();
  return out;
}

std::array<double, 6> GeometryFit::standardErrors(const Eigen::MatrixXd& c) {
  std::array<double, 6> out{};
  for (int k = 0; k < kNumGlobals; ++k) out[static_cast<std::size_t>(k)] = std::sqrt(std::max(0.0, c(k, k)));
  return out;
}

std::vector<double> GeometryFit::apertureVariances(const Eigen::VectorXd& p,
                                                   const std::vector<GeometryObservation>& obs) const {
  Eigen::MatrixXd a;
  Eigen::VectorXd b;
  normalEquations(p, obs, a, b);
  const double variance = residualVariance(p, obs);
  std::vector<double> out(base_.apertures_um.size(), 0.0);
  for (std::size_t k = 0; k < out.size(); ++k) {
    const Eigen::Index at = kNumGlobals + 2 * static_cast<Eigen::Index>(k);
    if (free_[static_cast<std::size_t>(at)])
      out[k] = 0.5 * Eigen::Matrix2d(a.block<2, 2>(at, at)).inverse().trace() * variance;
  }
  return out;
}

std::vector<double> GeometryFit::residualNorms(const Eigen::VectorXd& p,
                                               const std::vector<GeometryObservation>& obs) const {
  const MaskGeometry g = apply(p);
  std::vector<double> out;
  Eigen::Vector2d q;
  for (const auto& o : obs)
    out.push_back(predict(g, o, q) ? (o.measured_px - q).norm() : std::numeric_limits<double>::infinity());
  return out;
}

double robustSigma(std::vector<double> values) {
  if (values.empty()) return 0.0;
  std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(values.size() / 2), values.end());
  return 1.4826 * values[values.size() / 2];
}

}  // namespace dss
