#include "digital_sun_sensor/model/spot_bias.h"

#include <Eigen/Dense>
#include <algorithm>
#include <array>
#include <cmath>
#include <stdexcept>
#include <string>

#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/model/unit_calibration.h"
#include "geometric_solve.h"

namespace dss {

void SpotBias::addTo(const Eigen::Vector2d& angles_rad, std::vector<Eigen::Vector2d>& group_spots_um) const {
  if (!active()) return;
  const auto t = AngleCorrection::terms(degree, angles_rad.x() / angle_scale_rad, angles_rad.y() / angle_scale_rad);
  std::vector<Eigen::Vector2d> per_class(x_um.size(), Eigen::Vector2d::Zero());
  for (std::size_t c = 0; c < per_class.size(); ++c)
    for (std::size_t k = 0; k < t.size(); ++k) per_class[c] += t[k] * Eigen::Vector2d(x_um[c][k], y_um[c][k]);
  for (std::size_t g = 0; g < group_spots_um.size() && g < group_class.size(); ++g)
    group_spots_um[g] += per_class[static_cast<std::size_t>(group_class[g])];
}

SpotBias SpotBias::at(double height_change_um) const {
  SpotBias out = *this;
  out.by_height.clear();
  if (!active() || by_height.empty()) return out;
  std::vector<double> heights;
  for (const SpotBiasChange& c : by_height) heights.push_back(c.height_change_um);
  for (const auto& [entry, weight] : heightInterpolation(heights, height_change_um)) {
    if (entry < 0) continue;
    const SpotBiasChange& c = by_height[static_cast<std::size_t>(entry)];
    if (c.degree == AngleCorrection::kNone) continue;
    // The terms of a lower degree are the first of a higher one's.
    if (c.degree > out.degree) {
      out.degree = c.degree;
      for (auto* axis : {&out.x_um, &out.y_um})
        for (auto& coefficients : *axis) coefficients.resize(AngleCorrection::termCount(c.degree), 0.0);
    }
    for (std::size_t k = 0; k < out.x_um.size(); ++k)
      for (std::size_t t = 0; t < c.x_um[k].size(); ++t) {
        out.x_um[k][t] += weight * c.x_um[k][t];
        out.y_um[k][t] += weight * c.y_um[k][t];
      }
  }
  return out;
}

void SpotBias::validate(int groups) const {
  if (!active()) return;
  auto fail = [](const std::string& what) { throw std::invalid_argument("spot bias: " + what); };
  if (degree < 0 || degree > AngleCorrection::kMaxDegree)
    fail("degree " + std::to_string(degree) + " is outside 0.." + std::to_string(AngleCorrection::kMaxDegree));
  if (!(angle_scale_rad > 0.0) || !std::isfinite(angle_scale_rad)) fail("the angle scale must be positive");
  if (static_cast<int>(group_class.size()) != groups)
    fail(std::to_string(group_class.size()) + " group classes for a head of " + std::to_string(groups) + " groups");
  if (x_um.empty() || x_um.size() != y_um.size()) fail("needs one x and one y coefficient list per class");
  for (int c : group_class)
    if (c < 0 || c >= static_cast<int>(x_um.size()))
      fail("group class " + std::to_string(c) + " of " + std::to_string(x_um.size()));
  const std::size_t n = AngleCorrection::termCount(degree);
  for (const auto* axis : {&x_um, &y_um})
    for (const auto& c : *axis) {
      if (c.size() != n)
        fail("degree " + std::to_string(degree) + " needs " + std::to_string(n) +
             " coefficients per class and axis, not " + std::to_string(c.size()));
      for (double v : c)
        if (!std::isfinite(v)) fail("a coefficient is not finite");
    }
  for (std::size_t e = 0; e < by_height.size(); ++e) {
    const SpotBiasChange& c = by_height[e];
    const std::string at = "the change at " + std::to_string(c.height_change_um) + " um: ";
    if (!std::isfinite(c.height_change_um) || c.height_change_um == 0.0)
      fail("a change's height change must be finite and non-zero");
    for (std::size_t other = 0; other < e; ++other)
      if (by_height[other].height_change_um == c.height_change_um) fail(at + "given twice");
    if (c.degree < AngleCorrection::kNone || c.degree > AngleCorrection::kMaxDegree)
      fail(at + "degree " + std::to_string(c.degree) + " is outside -1.." +
           std::to_string(AngleCorrection::kMaxDegree));
    const std::size_t classes = c.degree == AngleCorrection::kNone ? 0 : x_um.size();
    if (c.x_um.size() != classes || c.y_um.size() != classes)
      fail(at + "needs " + std::to_string(classes) + " coefficient lists per axis");
    const std::size_t terms = AngleCorrection::termCount(std::max(c.degree, 0));
    for (const auto* axis : {&c.x_um, &c.y_um})
      for (const auto& coefficients : *axis) {
        if (coefficients.size() != terms)
          fail(at + "degree " + std::to_string(c.degree) + " needs " + std::to_string(terms) +
               " coefficients per class and axis, not " + std::to_string(coefficients.size()));
        for (double v : coefficients)
          if (!std::isfinite(v)) fail(at + "a coefficient is not finite");
      }
  }
}

std::vector<int> spotBiasClasses(const std::vector<double>& group_flux) {
  std::vector<int> out(group_flux.size(), -1);
  std::vector<double> class_flux;
  for (std::size_t g = 0; g < group_flux.size(); ++g) {
    for (std::size_t c = 0; c < class_flux.size() && out[g] < 0; ++c)
      if (std::abs(group_flux[g] - class_flux[c]) <= 0.01 * std::max(group_flux[g], class_flux[c]))
        out[g] = static_cast<int>(c);
    if (out[g] < 0) {
      out[g] = static_cast<int>(class_flux.size());
      class_flux.push_back(group_flux[g]);
    }
  }
  return out;
}

namespace {

struct SpotOffset {
  int spot_class = 0;
  int fold = 0;
  std::vector<double> terms;  // at the maximum degree
  Eigen::Vector2d offset_um;
  double weight = 0.0;
};

// Terms of total degree <= d are the first termCount(d) of a higher degree's.
Eigen::VectorXd head(const std::vector<double>& terms, std::size_t n) {
  return Eigen::Map<const Eigen::VectorXd>(terms.data(), static_cast<Eigen::Index>(n));
}

// Weighted least squares of one class's offsets on the first n terms (a
// trace-relative ridge keeps a sparsely seen corner finite), leaving out the
// spots of fold `skip_fold`. Zero with fewer spots than terms: a class the
// images hardly show keeps no bias.
std::array<Eigen::VectorXd, 2> fitClass(const std::vector<SpotOffset>& spots, int spot_class, std::size_t n,
                                        int skip_fold) {
  Eigen::MatrixXd a = Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(n), static_cast<Eigen::Index>(n));
  Eigen::MatrixXd b = Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(n), 2);
  std::size_t count = 0;
  for (const auto& s : spots) {
    if (s.spot_class != spot_class || s.fold == skip_fold) continue;
    const Eigen::VectorXd t = head(s.terms, n);
    a.noalias() += s.weight * t * t.transpose();
    b.noalias() += s.weight * t * s.offset_um.transpose();
    ++count;
  }
  if (count < n)
    return {Eigen::VectorXd::Zero(static_cast<Eigen::Index>(n)), Eigen::VectorXd::Zero(static_cast<Eigen::Index>(n))};
  a.diagonal().array() += 1e-9 * a.trace() / static_cast<double>(n);
  const Eigen::MatrixXd x = a.ldlt().solve(b);
  return {x.col(0), x.col(1)};
}

}  // namespace

SpotBiasFit fitSpotBias(const Model& model, const std::vector<UnitImage>& images, int max_degree,
                        bool change_from_model_bias) {
  if (!model.net->geometry()) throw std::invalid_argument("spot bias: the model has no geometric head");
  if (max_degree < 0 || max_degree > AngleCorrection::kMaxDegree)
    throw std::invalid_argument("spot bias: degree " + std::to_string(max_degree) + " is outside 0.." +
                                std::to_string(AngleCorrection::kMaxDegree));
  geometric::Design design = geometric::designOf(*model.net->geometry());
  if (!change_from_model_bias) design.spot_bias = SpotBias{};  // the readings against the ray trace alone
  const geometric::Options options = geometric::solveOptions(model);
  std::vector<double> group_flux(static_cast<std::size_t>(design.groups), 0.0);
  for (std::size_t k = 0; k < design.group.size(); ++k)
    group_flux[static_cast<std::size_t>(design.group[k])] += design.flux[k];
  SpotBiasFit fit;
  fit.bias.angle_scale_rad = model.meta.angle_scale_rad;
  fit.bias.group_class = spotBiasClasses(group_flux);
  const int classes = 1 + *std::max_element(fit.bias.group_class.begin(), fit.bias.group_class.end());

  std::vector<SpotOffset> spots;
  std::vector<geometric::Site> sites;
  const std::vector<Eigen::Vector2d> targets = uncorrectedAngles(model, images);
  for (std::size_t i = 0; i < images.size(); ++i) {
    sites.clear();
    for (std::size_t k = 0; k < images[i].site_um.size(); ++k)
      sites.push_back({images[i].site_um[k], images[i].site_weight[k]});
    const Eigen::Vector2d& at = targets[i];
    const geometric::Reading r = geometric::readSpots(design, sites, at, options.gate_um, options);
    const std::vector<double> w = geometric::solveWeights(r, options);
    const auto predicted = geometric::groupSpots(design, at);
    const auto t =
        AngleCorrection::terms(max_degree, at.x() / fit.bias.angle_scale_rad, at.y() / fit.bias.angle_scale_rad);
    for (std::size_t g = 0; g < w.size(); ++g) {
      if (!(w[g] > 0.0) || r.cut[g]) continue;
      spots.push_back({fit.bias.group_class[g], static_cast<int>(i % 2), t, r.centroid[g] - predicted[g], w[g]});
    }
  }
  fit.spots = spots.size();
  double weight = 0.0, before = 0.0;
  for (const auto& s : spots) weight += s.weight, before += s.weight * s.offset_um.squaredNorm();
  if (!(weight > 0.0))
    throw std::invalid_argument("spot bias: no whole spot in " + std::to_string(images.size()) + " images");
  fit.rms_before_um = std::sqrt(before / weight);

  // Two-fold cross-validation of the degree: each fold's spots against the other's fit.
  auto squaredError = [&](const std::vector<std::array<Eigen::VectorXd, 2>>& per_class, std::size_t n, int fold) {
    double sum = 0.0;
    for (const auto& s : spots) {
      if (fold >= 0 && s.fold != fold) continue;
      const auto& c = per_class[static_cast<std::size_t>(s.spot_class)];
      const Eigen::VectorXd t = head(s.terms, n);
      sum += s.weight * (s.offset_um - Eigen::Vector2d(c[0].dot(t), c[1].dot(t))).squaredNorm();
    }
    return sum;
  };
  int best = AngleCorrection::kNone;
  double best_rms = fit.rms_before_um;
  fit.cross_validated_rms_um.push_back(best_rms);
  for (int d = 0; d <= max_degree; ++d) {
    const std::size_t n = AngleCorrection::termCount(d);
    double sum = 0.0;
    for (int fold = 0; fold < 2; ++fold) {
      std::vector<std::array<Eigen::VectorXd, 2>> per_class;
      for (int c = 0; c < classes; ++c) per_class.push_back(fitClass(spots, c, n, fold));
      sum += squaredError(per_class, n, fold);
    }
    const double rms = std::sqrt(sum / weight);
    fit.cross_validated_rms_um.push_back(rms);
    if (rms < best_rms) best_rms = rms, best = d;
  }
  fit.bias.degree = best;
  fit.rms_after_um = fit.rms_before_um;
  if (best == AngleCorrection::kNone) {
    fit.bias.group_class.clear();
    return fit;
  }
  const std::size_t n = AngleCorrection::termCount(best);
  std::vector<std::array<Eigen::VectorXd, 2>> per_class;
  for (int c = 0; c < classes; ++c) {
    per_class.push_back(fitClass(spots, c, n, -1));
    fit.bias.x_um.emplace_back(per_class.back()[0].data(), per_class.back()[0].data() + n);
    fit.bias.y_um.emplace_back(per_class.back()[1].data(), per_class.back()[1].data() + n);
  }
  fit.rms_after_um = std::sqrt(squaredError(per_class, n, -1) / weight);
  return fit;
}

void setSpotBias(Model& model, const SpotBias& bias) {
  if (!model.net->geometry()) throw std::invalid_argument("spot bias: the model has no geometric head");
  model.net->geometry()->setSpotBias(bias);
  model.meta.spot_bias = bias;
}

}  // namespace dss
