#include "digital_sun_sensor/train/bias_calibration.h"

#include <yaml-cpp/yaml.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/model/physics_prior.h"
#include "digital_sun_sensor/model/sscnn.h"
#include "digital_sun_sensor/model/unit_calibration.h"
#include "held_out.h"

namespace dss {
namespace {

// Errors beyond this many times the median absolute error are not smooth bias.
constexpr double kOutlierFactor = 20.0;
// A richer correction must lower the cross-validated RMS by more than this
// fraction to be chosen over a simpler one (parsimony: noise in the choice).
constexpr double kRequiredGain = 0.01;

// Least-squares coefficients [terms, 2] of the first `terms` basis columns of
// rows `rows` of `basis` against the errors (one cross-validation fold).
Eigen::MatrixXd fit(const Eigen::MatrixXd& basis, const Eigen::MatrixXd& errors, const std::vector<Eigen::Index>& rows,
                    Eigen::Index terms) {
  Eigen::MatrixXd a(rows.size(), terms), b(rows.size(), 2);
  for (std::size_t r = 0; r < rows.size(); ++r) {
    a.row(r) = basis.row(rows[r]).head(terms);
    b.row(r) = errors.row(rows[r]);
  }
  return a.colPivHouseholderQr().solve(b);
}

}  // namespace

BiasCalibration calibrateBias(Model& model, const TrainingSet& data, std::size_t max_samples, int max_degree,
                              bool add_to_model_correction, const SampleProgress& progress) {
  if (max_degree < AngleCorrection::kNone || max_degree > AngleCorrection::kMaxDegree)
    throw std::invalid_argument("bias calibration: maximum degree " + std::to_string(max_degree) + " is outside " +
                                std::to_string(AngleCorrection::kNone) + ".." +
                                std::to_string(AngleCorrection::kMaxDegree));
  // The network's own bias is what is fitted, or what the model's correction leaves of it.
  const AngleCorrection base = add_to_model_correction ? model.meta.angle_correction : AngleCorrection{};
  model.meta.angle_correction = base;
  const std::vector<HeldOutPrediction> held_out =
      predictHeldOut(model, data, max_samples, "bias calibration", progress);
  if (held_out.empty()) throw std::invalid_argument("bias calibration: the model found no sun in any sample");

  // Normalized estimates and errors; the outlier bound from the median error.
  const double scale = model.meta.angle_scale_rad;
  std::vector<double> magnitudes;
  for (const auto& h : held_out)
    magnitudes.push_back(std::max(std::abs(h.prediction.alpha_rad - h.sample->alpha_rad),
                                  std::abs(h.prediction.beta_rad - h.sample->beta_rad)));
  std::vector<double> sorted = magnitudes;
  std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
  const double bound = kOutlierFactor * sorted[sorted.size() / 2];
  std::vector<const HeldOutPrediction*> kept;
  for (std::size_t k = 0; k < held_out.size(); ++k)
    if (magnitudes[k] <= bound) kept.push_back(&held_out[k]);

  BiasCalibration c;
  c.samples = kept.size();
  c.outliers = held_out.size() - kept.size();
  const int top = std::max(max_degree, 0);
  const auto n = static_cast<Eigen::Index>(kept.size());
  Eigen::MatrixXd basis(n, static_cast<Eigen::Index>(AngleCorrection::termCount(top)));
  Eigen::MatrixXd errors(n, 2);
  for (Eigen::Index r = 0; r < n; ++r) {
    const Prediction& p = kept[r]->prediction;
    const auto t = AngleCorrection::terms(top, p.alpha_rad / scale, p.beta_rad / scale);
    basis.row(r) = Eigen::Map<const Eigen::RowVectorXd>(t.data(), static_cast<Eigen::Index>(t.size()));
    errors(r, 0) = (p.alpha_rad - kept[r]->sample->alpha_rad) / scale;
    errors(r, 1) = (p.beta_rad - kept[r]->sample->beta_rad) / scale;
  }
  auto rmsDeg = [&](const Eigen::MatrixXd& e) {
    return std::sqrt(e.squaredNorm() / std::max<double>(1.0, static_cast<double>(e.size()))) * scale * kDegPerRad;
  };

  // Two folds, even and odd samples: each fitted on one and scored on the other.
  std::vector<Eigen::Index> folds[2];
  for (Eigen::Index r = 0; r < n; ++r) folds[r % 2].push_back(r);
  c.cross_validated_rms_deg.push_back(rmsDeg(errors));
  c.degree = AngleCorrection::kNone;
  double best = c.cross_validated_rms_deg.front();
  for (int degree = 0; degree <= max_degree; ++degree) {
    const auto terms = static_cast<Eigen::Index>(AngleCorrection::termCount(degree));
    // Too few samples to fit this many terms: held-out errors would say nothing.
    if (static_cast<Eigen::Index>(folds[1].size()) < 3 * terms) break;
    double sum = 0.0;
    for (int f = 0; f < 2; ++f) {
      const Eigen::MatrixXd coefficients = fit(basis, errors, folds[f], terms);
      for (const Eigen::Index r : folds[1 - f])
        sum += (errors.row(r) - basis.row(r).head(terms) * coefficients).squaredNorm();
    }
    const double rms = std::sqrt(sum / std::max<double>(1.0, 2.0 * static_cast<double>(n))) * scale * kDegPerRad;
    c.cross_validated_rms_deg.push_back(rms);
    if (rms < best * (1.0 - kRequiredGain)) {
      best = rms;
      c.degree = degree;
    }
  }

  AngleCorrection& correction = model.meta.angle_correction;
  Eigen::MatrixXd residual = errors;
  if (c.degree != AngleCorrection::kNone) {
    const auto terms = static_cast<Eigen::Index>(AngleCorrection::termCount(c.degree));
    const Eigen::MatrixXd coefficients = basis.leftCols(terms).colPivHouseholderQr().solve(errors);
    // The terms of a lower degree are the first of a higher one's: the sum
    // of two corrections is their coefficients added.
    correction.degree = std::max(base.degree, c.degree);
    const std::size_t total_terms = AngleCorrection::termCount(correction.degree);
    correction.alpha.resize(total_terms, 0.0);
    correction.beta.resize(total_terms, 0.0);
    for (Eigen::Index k = 0; k < terms; ++k) {
      correction.alpha[static_cast<std::size_t>(k)] += coefficients(k, 0);
      correction.beta[static_cast<std::size_t>(k)] += coefficients(k, 1);
    }
    correction.validate();
    residual -= basis.leftCols(terms) * coefficients;
  }
  c.rms_alpha_before_deg = rmsDeg(errors.col(0));
  c.rms_beta_before_deg = rmsDeg(errors.col(1));
  c.rms_alpha_after_deg = rmsDeg(residual.col(0));
  c.rms_beta_after_deg = rmsDeg(residual.col(1));

  YAML::Node metrics = YAML::Load(model.meta.metrics_yaml);
  metrics["angle_correction_degree"] = correction.degree;
  metrics["angle_correction_samples"] = c.samples;
  metrics["angle_correction_cv_rms_deg_none"] = c.cross_validated_rms_deg.front();
  metrics["angle_correction_cv_rms_deg"] = c.cross_validated_rms_deg[static_cast<std::size_t>(c.degree + 1)];
  model.meta.metrics_yaml = YAML::Dump(metrics);
  return c;
}

HeightCalibration calibrateHeightCorrection(Model& model, const TrainingSet& data, double height_change_um,
                                            std::size_t max_samples, int max_degree, int spot_bias_degree) {
  const std::string what = "height correction";
  SensorGeometry geometry = model.net->geometry();
  if (!geometry) throw std::invalid_argument(what + ": the model's head is not geometric");
  if (!std::isfinite(height_change_um) || height_change_um == 0.0)
    throw std::invalid_argument(what + ": the height change must be finite and non-zero");
  if (model.heightChangeUm() != 0.0)
    throw std::invalid_argument(what +
                                ": the model holds a unit's geometry (its mask height differs from the design's "
                                "by " +
                                std::to_string(model.heightChangeUm()) + " um): use the family model");
  // Fitted against the design's correction and spot bias alone, the other entries set aside.
  std::vector<HeightCorrection> entries;
  for (const HeightCorrection& h : model.meta.height_corrections)
    if (h.height_change_um != height_change_um) entries.push_back(h);
  SpotBias bias = model.meta.spot_bias;
  bias.by_height.erase(std::remove_if(bias.by_height.begin(), bias.by_height.end(),
                                      [&](const SpotBiasChange& c) { return c.height_change_um == height_change_um; }),
                       bias.by_height.end());
  SpotBias design_bias = bias;
  design_bias.by_height.clear();
  model.meta.height_corrections.clear();
  const MaskGeometry design = geometry->maskGeometry();
  MaskGeometry moved = design;
  moved.height_um += height_change_um;
  const AngleCorrection base = model.meta.angle_correction;
  const std::string metrics = model.meta.metrics_yaml;
  // The design's prior as the model holds it (computed through the head's
  // geometry it differs slightly from the one the model was created with).
  const auto [prior_table, prior_extent_x, prior_extent_y] = model.net->geometricPriorCopy();
  auto restore = [&] {
    geometry->setMaskGeometry(design);
    if (prior_table.defined()) model.net->initGeometricPrior(prior_table, prior_extent_x, prior_extent_y);
    model.meta.angle_correction = base;
    model.meta.metrics_yaml = metrics;
    model.meta.height_corrections = entries;
    setSpotBias(model, bias);
  };
  setSpotBias(model, design_bias);
  setHeadGeometry(model, moved);  // the prior too: the moved spots at the field's edge lie past the design's extent
  HeightCalibration c;
  try {
    c.correction = calibrateBias(model, data, max_samples, max_degree, /*add_to_model_correction=*/true);
    // The bias's change, read where the moved correction takes the solve to the truth.
    if (bias.active() && spot_bias_degree != AngleCorrection::kNone)
      c.spot_bias = fitSpotBias(model, readUnitImages(model, data, max_samples), spot_bias_degree,
                                /*change_from_model_bias=*/true);
  } catch (...) {
    restore();
    throw;
  }
  // The added terms: the fitted correction less the design's.
  HeightCorrection h;
  h.height_change_um = height_change_um;
  h.change = model.meta.angle_correction;
  for (std::size_t k = 0; k < base.alpha.size(); ++k) {
    h.change.alpha[k] -= base.alpha[k];
    h.change.beta[k] -= base.beta[k];
  }
  if (c.spot_bias) {
    SpotBiasChange change;
    change.height_change_um = height_change_um;
    change.degree = c.spot_bias->bias.degree;
    change.x_um = c.spot_bias->bias.x_um;
    change.y_um = c.spot_bias->bias.y_um;
    bias.by_height.push_back(std::move(change));
  }
  restore();
  if (c.correction.degree != AngleCorrection::kNone) model.meta.height_corrections.push_back(h);
  return c;
}

}  // namespace dss
