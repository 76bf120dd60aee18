#include "digital_sun_sensor/train/sigma_calibration.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <stdexcept>

#include "digital_sun_sensor/model/model.h"
#include "held_out.h"

namespace dss {

SigmaCalibration calibrateSigma(Model& model, const TrainingSet& data, std::size_t max_samples,
                                const SampleProgress& progress) {
  model.meta.sigma_site_law = {};  // refitted below, from the head's (or the constant's) own sigma
  // A unit calibration's geometry sigma is not fitted here: on the images
  // the geometry was fitted to, its error is absent; on fresh ones it adds.
  const std::array<double, 2> geometry_sigma = model.meta.geometry_sigma_rad;
  model.meta.geometry_sigma_rad = {0.0, 0.0};
  std::vector<HeldOutPrediction> held_out;
  try {
    held_out = predictHeldOut(model, data, max_samples, "sigma calibration", progress);
  } catch (...) {
    model.meta.geometry_sigma_rad = geometry_sigma;
    throw;
  }
  model.meta.geometry_sigma_rad = geometry_sigma;
  std::vector<ErrorAndSigma> za, zb;
  std::vector<int> sites;
  for (const HeldOutPrediction& h : held_out) {
    const Prediction& p = h.prediction;
    za.push_back({p.alpha_rad - h.sample->alpha_rad, std::sqrt(p.alpha_variance_rad2)});
    zb.push_back({p.beta_rad - h.sample->beta_rad, std::sqrt(p.beta_variance_rad2)});
    sites.push_back(p.active_sites);
  }
  SigmaCalibration c;
  c.samples = za.size();
  c.alpha_before = measureCoverage(za);
  c.beta_before = measureCoverage(zb);
  // Averaged over mirror images that swap the axes (dihedral), each axis's
  // variance is the same mix of the head's two outputs, and the sensor's
  // alpha and beta errors are alike by symmetry: one factor (or one constant)
  // for both, fitted on the errors of both.
  const bool axes_exchange = model.meta.inference_symmetry == InferenceSymmetry::kDihedral;
  std::vector<ErrorAndSigma> both = za;
  both.insert(both.end(), zb.begin(), zb.end());
  c.scale_alpha = sigmaScaleForCoverage(axes_exchange ? both : za);
  c.scale_beta = axes_exchange ? c.scale_alpha : sigmaScaleForCoverage(zb);
  for (auto& s : za) s.sigma_rad *= c.scale_alpha;
  for (auto& s : zb) s.sigma_rad *= c.scale_beta;
  c.alpha_after = measureCoverage(za);
  c.beta_after = measureCoverage(zb);

  // The same 1-sigma level from one sigma per axis, following the lit-site
  // count where that covers images of few and many lit sites alike: where the
  // head's shape does not follow the error (its 2 and 3 sigma coverage further
  // from the Gaussian's than the constant's), the constant is the honest answer.
  auto sited = [&](const std::vector<ErrorAndSigma>& z) {
    std::vector<SitedError> out;
    for (std::size_t k = 0; k < z.size(); ++k) out.push_back({z[k].error_rad, sites[k]});
    return out;
  };
  std::vector<SitedError> sited_alpha = sited(za);
  const std::vector<SitedError> sited_beta = sited(zb);
  if (axes_exchange) {
    sited_alpha.insert(sited_alpha.end(), sited_beta.begin(), sited_beta.end());  // one group: both axes
    c.site_law = fitSiteSigmaLaw({sited_alpha});
  } else {
    c.site_law = fitSiteSigmaLaw({sited_alpha, sited_beta});
  }
  auto constant = [&](std::vector<ErrorAndSigma> z) {
    std::vector<ErrorAndSigma> fit = axes_exchange ? both : z;
    for (std::size_t k = 0; k < fit.size(); ++k) fit[k].sigma_rad = c.site_law.factor(sites[k % sites.size()]);
    const double sigma = sigmaScaleForCoverage(fit);
    for (std::size_t k = 0; k < z.size(); ++k) z[k].sigma_rad = sigma * c.site_law.factor(sites[k]);
    return std::make_pair(sigma, measureCoverage(z));
  };
  auto shapeError = [](const Coverage& a, const Coverage& b) {
    return std::abs(a.within[1] - 0.9545) + std::abs(a.within[2] - 0.9973) + std::abs(b.within[1] - 0.9545) +
           std::abs(b.within[2] - 0.9973);
  };
  const auto [sigma_alpha, constant_alpha] = constant(za);
  const auto [sigma_beta, constant_beta] = constant(zb);
  YAML::Node metrics = YAML::Load(model.meta.metrics_yaml);
  if (sigma_alpha > 0 && sigma_beta > 0 &&
      shapeError(constant_alpha, constant_beta) < shapeError(c.alpha_after, c.beta_after)) {
    c.constant = true;
    c.alpha_after = constant_alpha;
    c.beta_after = constant_beta;
    c.constant_sigma_alpha_rad = sigma_alpha;
    c.constant_sigma_beta_rad = sigma_beta;
    model.setConstantSigma(sigma_alpha, sigma_beta);
    model.meta.sigma_site_law = c.site_law;
    metrics["sigma_mode"] = c.site_law.active() ? "lit_sites" : "constant";
    metrics["sigma_constant_alpha_rad"] = sigma_alpha;
    metrics["sigma_constant_beta_rad"] = sigma_beta;
  } else {
    c.site_law = {};
    model.scaleSigma(c.scale_alpha, c.scale_beta);
    if (const auto sigma = model.constantSigma()) {
      // A constant from an earlier calibration, scaled: still a constant.
      c.constant = true;
      c.constant_sigma_alpha_rad = (*sigma)[0];
      c.constant_sigma_beta_rad = (*sigma)[1];
      metrics["sigma_mode"] = "constant";
      metrics["sigma_constant_alpha_rad"] = c.constant_sigma_alpha_rad;
      metrics["sigma_constant_beta_rad"] = c.constant_sigma_beta_rad;
    } else {
      metrics["sigma_mode"] = "head";
      // The factors since training: a recalibration multiplies into the record.
      auto total = [&](const char* key, double factor) {
        return metrics[key] ? metrics[key].as<double>() * factor : factor;
      };
      metrics["sigma_scale_alpha"] = total("sigma_scale_alpha", c.scale_alpha);
      metrics["sigma_scale_beta"] = total("sigma_scale_beta", c.scale_beta);
    }
  }
  if (c.site_law.active()) {
    metrics["sigma_site_exponent"] = c.site_law.exponent;
    metrics["sigma_site_reference"] = c.site_law.reference_sites;
  } else {
    metrics.remove("sigma_site_exponent");
    metrics.remove("sigma_site_reference");
  }
  metrics["sigma_calibration_samples"] = c.samples;
  model.meta.metrics_yaml = YAML::Dump(metrics);
  return c;
}

std::optional<SigmaCalibration> calibrateSigmaWhereTooSmall(Model& model, const TrainingSet& data,
                                                            std::size_t max_samples, double min_coverage) {
  Model trial = deserializeModel(serializeModel(model), "sigma calibration (a copy of the model)");
  const SigmaCalibration c = calibrateSigma(trial, data, max_samples);
  if (std::min(c.alpha_before.within[0], c.beta_before.within[0]) >= min_coverage) return std::nullopt;
  model = std::move(trial);
  return c;
}

}  // namespace dss
