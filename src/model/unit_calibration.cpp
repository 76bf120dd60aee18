#include "digital_sun_sensor/model/unit_calibration.h"

#include <yaml-cpp/yaml.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <cmath>
#include <functional>
#include <limits>
#include <stdexcept>

#include "digital_sun_sensor/baseline/geometry_fit.h"
#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/model/input_envelope.h"
#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/model/physics_prior.h"
#include "digital_sun_sensor/model/sparse_input.h"
#include "digital_sun_sensor/sim/geometry.h"
#include "geometric_solve.h"

namespace dss {
namespace {

constexpr std::size_t kSamplesPerPass = 64;
// The geometry sigma: images re-solved (evenly spaced) through geometries
// drawn from the fit's covariance (fixed seed: a calibration is repeatable),
// scaled down by kSigmaStep and the change scaled back up. The draws are
// linearised so: along the directions the data leave to the aperture prior
// (a common offset or rotation taken by every aperture's position) a full
// draw moves the apertures by tens of micrometres, whose second-order
// effect on the spots is not a calibration error.
constexpr std::size_t kSigmaImages = 100;
constexpr int kSigmaDraws = 32;
constexpr std::uint64_t kSigmaSeed = 0x5161;
constexpr double kSigmaStep = 0.01;
// Refits that bring the aperture prior's weight to the fitted spot noise
// (one is typically enough).
constexpr int kPriorPasses = 4;

// One image as the network reads it: its lit sites with the weights the
// solve gives them, the model's estimate and the solve's residual.
struct ImageRead {
  UnitImage image;  // sites and truth
  Prediction prediction;
  double residual_per_dof = 0.0;
  std::size_t input = 0;  // index among the images read
};

void requireGeometricHead(const Model& model, const TrainingSet& data, const std::string& what) {
  if (!model.meta.arch.geometric_head)
    throw std::invalid_argument(what +
                                ": the model's head is not geometric (train it with --head geometric): it has "
                                "no geometry to fit");
  const InputSpec& a = data.spec();
  const InputSpec& b = model.meta.input;
  if (a.width_px != b.width_px || a.height_px != b.height_px || a.max_code != b.max_code ||
      a.threshold_dn != b.threshold_dn || a.black_level_dn != b.black_level_dn)
    throw std::invalid_argument(what + ": the images were not encoded with the model's input spec");
  if (data.size() == 0) throw std::invalid_argument(what + ": no images");
}

std::vector<const SparseSample*> evenlySpaced(const TrainingSet& data, std::size_t max_samples) {
  const std::size_t n = max_samples ? std::min(data.size(), max_samples) : data.size();
  std::vector<const SparseSample*> picked;
  for (std::size_t i = 0; i < n; ++i) picked.push_back(&data.samples()[i * data.size() / n]);
  return picked;
}

// The network over `count` inputs (eval mode, no autograd) in passes;
// `encode(first, last)` encodes a pass, `truth(i)` gives input i's angles.
// Images without a lit site are left out.
template <typename Encode, typename Truth>
std::vector<ImageRead> readImages(const Model& model, std::size_t count, const Encode& encode, const Truth& truth) {
  torch::NoGradGuard no_grad;
  model.net->eval();
  std::vector<ImageRead> out;
  for (std::size_t first = 0; first < count; first += kSamplesPerPass) {
    const std::size_t last = std::min(count, first + kSamplesPerPass);
    const sparse::SparseTensor input = encode(first, last);
    const SscnnOutput result = model.net->forward(input);
    const std::vector<Prediction> predictions = model.decode(result, *input.sites);
    std::vector<ImageRead> reads(last - first);
    const auto xy = result.solve_site_um.contiguous();
    const auto w = result.solve_site_weight.contiguous();
    const auto image = result.solve_site_image.to(torch::kLong).contiguous();
    const auto dof = result.solve_residual_per_dof.to(torch::kDouble).contiguous();
    const auto xy_a = xy.accessor<double, 2>();
    const auto w_a = w.accessor<double, 1>();
    const auto image_a = image.accessor<std::int64_t, 1>();
    for (std::int64_t i = 0; i < xy.size(0); ++i) {
      UnitImage& u = reads[static_cast<std::size_t>(image_a[i])].image;
      u.site_um.emplace_back(xy_a[i][0], xy_a[i][1]);
      u.site_weight.push_back(w_a[i]);
    }
    for (std::size_t b = 0; b < reads.size(); ++b) {
      const std::array<double, 2> angles = truth(first + b);
      reads[b].image.alpha_rad = angles[0];
      reads[b].image.beta_rad = angles[1];
      reads[b].prediction = predictions[b];
      reads[b].residual_per_dof = dof[static_cast<std::int64_t>(b)].item<double>();
      reads[b].input = first + b;
      if (predictions[b].active_sites > 0) out.push_back(std::move(reads[b]));
    }
  }
  return out;
}

std::vector<ImageRead> readSamples(const Model& model, const std::vector<const SparseSample*>& samples) {
  return readImages(
      model, samples.size(),
      [&](std::size_t first, std::size_t last) {
        return encodeSamples(
            {samples.begin() + static_cast<std::ptrdiff_t>(first), samples.begin() + static_cast<std::ptrdiff_t>(last)},
            model.meta.input);
      },
      [&](std::size_t i) {
        return std::array<double, 2>{samples[i]->alpha_rad, samples[i]->beta_rad};
      });
}

// Per image the solve's angles [rad] through `in_use` from which the head's
// learned correction and the model's angle correction (at that geometry's
// mask height) give the true angles (fixed-point iteration: both corrections
// are small and smooth).
std::vector<Eigen::Vector2d> solvedTargets(const Model& model, const std::vector<UnitImage>& images,
                                           const MaskGeometry& in_use) {
  torch::NoGradGuard no_grad;
  const double s = model.meta.angle_scale_rad;
  const auto n = static_cast<std::int64_t>(images.size());
  auto truth = torch::zeros({n, 2}, torch::kDouble);
  for (std::int64_t i = 0; i < n; ++i) {
    truth[i][0] = images[static_cast<std::size_t>(i)].alpha_rad / s;
    truth[i][1] = images[static_cast<std::size_t>(i)].beta_rad / s;
  }
  auto target = truth.clone();
  const auto& design_height_um = model.net->geometry()->designHeightUm();
  const UnitAngleCorrection correction(model.meta.angle_correction, model.meta.height_corrections,
                                       design_height_um ? in_use.height_um - *design_height_um : 0.0);
  for (int it = 0; it < 4; ++it) {
    auto output = model.net->correctSolvedAngles(target.to(torch::kFloat)).to(torch::kDouble).contiguous();
    const auto o = output.accessor<double, 2>();
    for (std::int64_t i = 0; i < n; ++i) {
      const auto bias = correction.bias(o[i][0], o[i][1]);
      output[i][0] = o[i][0] - bias[0];
      output[i][1] = o[i][1] - bias[1];
    }
    target += truth - output;
  }
  std::vector<Eigen::Vector2d> out(images.size());
  const auto t = target.accessor<double, 2>();
  for (std::int64_t i = 0; i < n; ++i) out[static_cast<std::size_t>(i)] = Eigen::Vector2d(t[i][0], t[i][1]) * s;
  return out;
}

// The whole spots each image shows at its target angles through `design`,
// weighted as the solve weighs them (relative to `weight_unit`).
std::vector<GeometryObservation> observe(const geometric::Design& design, const std::vector<UnitImage>& images,
                                         const std::vector<Eigen::Vector2d>& targets, const geometric::Options& options,
                                         double weight_unit) {
  std::vector<std::vector<int>> members(static_cast<std::size_t>(design.groups));
  std::vector<std::vector<double>> fluxes(members.size());
  for (std::size_t k = 0; k < design.group.size(); ++k) {
    members[static_cast<std::size_t>(design.group[k])].push_back(static_cast<int>(k));
    fluxes[static_cast<std::size_t>(design.group[k])].push_back(design.flux[k]);
  }
  std::vector<GeometryObservation> out;
  std::vector<geometric::Site> sites;
  for (std::size_t i = 0; i < images.size(); ++i) {
    sites.clear();
    for (std::size_t k = 0; k < images[i].site_um.size(); ++k)
      sites.push_back({images[i].site_um[k], images[i].site_weight[k]});
    const geometric::Reading r = geometric::readSpots(design, sites, targets[i], options.gate_um, options);
    const std::vector<double> w = geometric::solveWeights(r, options);
    // The geometry fitted predicts the ray trace's spots: the bias comes off the readings.
    std::vector<Eigen::Vector2d> bias(w.size(), Eigen::Vector2d::Zero());
    design.spot_bias.addTo(targets[i], bias);
    for (std::size_t g = 0; g < w.size(); ++g) {
      if (!(w[g] > 0.0) || r.cut[g]) continue;
      GeometryObservation o;
      o.sample = static_cast<int>(i);
      o.sun = sunVectorFromAngles(targets[i].x(), targets[i].y());
      o.apertures = members[g];
      if (members[g].size() > 1) o.fluxes = fluxes[g];
      o.measured_px = r.centroid[g] - bias[g];
      o.weight = w[g] / weight_unit;
      out.push_back(std::move(o));
    }
  }
  return out;
}

// Per observation sqrt(weight) x residual length [um at unit weight].
std::vector<double> weightedNorms(const GeometryFit& fit, const Eigen::VectorXd& p,
                                  const std::vector<GeometryObservation>& obs) {
  std::vector<double> norms = fit.residualNorms(p, obs);
  for (std::size_t k = 0; k < obs.size(); ++k) norms[k] *= std::sqrt(obs[k].weight);
  return norms;
}

double weightedRms(const GeometryFit& fit, const Eigen::VectorXd& p, const std::vector<GeometryObservation>& obs) {
  double sum = 0.0, weight = 0.0;
  const std::vector<double> norms = fit.residualNorms(p, obs);
  for (std::size_t k = 0; k < obs.size(); ++k)
    if (std::isfinite(norms[k])) sum += obs[k].weight * norms[k] * norms[k], weight += obs[k].weight;
  return weight > 0.0 ? std::sqrt(sum / weight) : 0.0;
}

// RMS change per axis of the images' solved angles [rad] (up to
// kSigmaImages, evenly spaced) when their spots are solved through kSigmaDraws
// geometries `draw` makes (fixed seed: repeatable) instead of `design`'s,
// divided by `scale`. With `linear_only`, images whose change exceeds
// kNonlinearFactor x the median image's are left out: for the linearised
// draws of a fit's covariance, a few solves near the field's edge change by
// a hundred times the rest (a 3x wide_ma unit on 400 lab images: 6 of 100
// images 0.01-0.04 deg, the median 0.0001), which made the geometry sigma
// 0.005 deg and put 99.6 % of its test errors within 1 sigma.
constexpr double kNonlinearFactor = 10.0;
std::array<double, 2> solveChangeRms(const geometric::Design& design, const std::vector<UnitImage>& images,
                                     const std::vector<Eigen::Vector2d>& targets, const geometric::Options& options,
                                     const std::function<MaskGeometry(Rng&)>& draw, double scale,
                                     bool linear_only = false) {
  std::vector<std::vector<geometric::Site>> sites;
  std::vector<Eigen::Vector2d> reference, solved;
  const std::size_t n = std::min(images.size(), kSigmaImages);
  for (std::size_t k = 0; k < n; ++k) {
    const std::size_t i = k * images.size() / n;
    if (images[i].site_um.empty()) continue;
    sites.emplace_back();
    for (std::size_t s = 0; s < images[i].site_um.size(); ++s)
      sites.back().push_back({images[i].site_um[s], images[i].site_weight[s]});
    reference.push_back(targets[i]);
    solved.push_back(geometric::solveImage(design, sites.back(), targets[i], options).angles_rad);
  }
  if (sites.empty()) return {0.0, 0.0};
  Rng rng(kSigmaSeed);
  geometric::Design geometry = design;
  std::vector<Eigen::Array2d> per_image(sites.size(), Eigen::Array2d::Zero());  // summed squares over the draws
  for (int d = 0; d < kSigmaDraws; ++d) {
    geometry.mask = draw(rng);
    for (std::size_t i = 0; i < sites.size(); ++i)
      per_image[i] +=
          ((geometric::solveImage(geometry, sites[i], reference[i], options).angles_rad - solved[i]) / scale)
              .array()
              .square();
  }
  double limit = std::numeric_limits<double>::infinity();
  if (linear_only) {
    std::vector<double> totals;
    for (const auto& s : per_image) totals.push_back(s.sum());
    std::nth_element(totals.begin(), totals.begin() + static_cast<std::ptrdiff_t>(totals.size() / 2), totals.end());
    limit = kNonlinearFactor * kNonlinearFactor * totals[totals.size() / 2];
  }
  Eigen::Array2d sum = Eigen::Array2d::Zero();
  std::size_t kept = 0;
  for (const auto& s : per_image)
    if (s.sum() <= limit) sum += s, ++kept;
  const Eigen::Array2d sigma = (sum / static_cast<double>(kSigmaDraws * std::max<std::size_t>(kept, 1))).sqrt();
  return {sigma[0], sigma[1]};
}

// The geometry sigma of a fit: geometries drawn from its covariance about p.
std::array<double, 2> geometrySigma(const GeometryFit& fit, const Eigen::VectorXd& p, const Eigen::MatrixXd& covariance,
                                    const geometric::Design& design, const std::vector<UnitImage>& images,
                                    const std::vector<Eigen::Vector2d>& targets, const geometric::Options& options) {
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(covariance);
  const Eigen::MatrixXd root = eigen.eigenvectors() * eigen.eigenvalues().cwiseMax(0.0).cwiseSqrt().asDiagonal();
  geometric::Design fitted = design;
  fitted.mask = fit.apply(p);
  Eigen::VectorXd z(p.size());
  const auto draw = [&](Rng& rng) {
    for (Eigen::Index k = 0; k < z.size(); ++k) z[k] = rng.normal();
    return fit.apply(p + kSigmaStep * (root * z));
  };
  return solveChangeRms(fitted, images, targets, options, draw, kSigmaStep, true);
}

double angleRmsDeg(const std::vector<ImageRead>& reads) {
  double sum = 0.0;
  for (const auto& r : reads) {
    const double da = r.prediction.alpha_rad - r.image.alpha_rad, db = r.prediction.beta_rad - r.image.beta_rad;
    sum += da * da + db * db;
  }
  return reads.empty() ? 0.0 : radToDeg(std::sqrt(sum / (2.0 * static_cast<double>(reads.size()))));
}

}  // namespace

geometric::Options geometric::solveOptions(const Model& model) {
  geometric::Options o;
  o.gate_um = model.meta.arch.geometric_gate_um;
  o.pitch_um = model.meta.arch.detector_pitch_um;
  o.width_px = model.meta.arch.detector_width_px;
  o.height_px = model.meta.arch.detector_height_px;
  o.symmetric_spots = model.meta.arch.geometric_symmetric_spots;
  return o;
}

std::vector<Eigen::Vector2d> uncorrectedAngles(const Model& model, const std::vector<UnitImage>& images) {
  return solvedTargets(model, images, model.net->geometry()->maskGeometry());
}

std::string UnitCalibrationReport::toYaml() const {
  YAML::Emitter out;
  out.SetDoublePrecision(6);  // a record for people: residuals and changes, not values read back
  out << YAML::BeginMap;
  out << YAML::Key << "images" << YAML::Value << images << YAML::Key << "images_used" << YAML::Value << images_used;
  out << YAML::Key << "spots" << YAML::Value << spots << YAML::Key << "outliers" << YAML::Value << outliers;
  out << YAML::Key << "iterations" << YAML::Value << iterations;
  out << YAML::Key << "free_parameters" << YAML::Value << YAML::Flow << free_parameters;
  out << YAML::Key << "spot_rms_um_before" << YAML::Value << spot_rms_um_before;
  out << YAML::Key << "spot_rms_um_after" << YAML::Value << spot_rms_um_after;
  out << YAML::Key << "angle_rms_deg_before" << YAML::Value << angle_rms_deg_before;
  out << YAML::Key << "angle_rms_deg_after" << YAML::Value << angle_rms_deg_after;
  out << YAML::Key << "geometry_sigma_deg" << YAML::Value << YAML::Flow << YAML::BeginSeq
      << radToDeg(geometry_sigma_rad[0]) << radToDeg(geometry_sigma_rad[1]) << YAML::EndSeq;
  out << YAML::Key << "aperture_position_sigma_um" << YAML::Value << YAML::Flow << aperture_sigma_um;
  // What the fit changed, in the geometry's own terms.
  double shift2 = 0.0;
  for (std::size_t k = 0; k < after.apertures_um.size(); ++k)
    shift2 += (after.apertures_um[k] - before.apertures_um[k]).squaredNorm();
  out << YAML::Key << "change" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "height_um" << YAML::Value << after.height_um - before.height_um;
  out << YAML::Key << "offset_um" << YAML::Value << YAML::Flow << YAML::BeginSeq
      << after.offset_x_um - before.offset_x_um << after.offset_y_um - before.offset_y_um << YAML::EndSeq;
  out << YAML::Key << "rotation_deg" << YAML::Value << radToDeg(after.rotation_rad - before.rotation_rad);
  out << YAML::Key << "tilt_deg" << YAML::Value << YAML::Flow << YAML::BeginSeq
      << radToDeg(after.tilt_x_rad - before.tilt_x_rad) << radToDeg(after.tilt_y_rad - before.tilt_y_rad)
      << YAML::EndSeq;
  out << YAML::Key << "aperture_shift_rms_um" << YAML::Value
      << (after.apertures_um.empty() ? 0.0 : std::sqrt(shift2 / static_cast<double>(after.apertures_um.size())));
  out << YAML::EndMap;
  out << YAML::EndMap;
  return out.c_str();
}

UnitCalibrationReport fitUnitGeometry(Model& model, const std::vector<UnitImage>& images,
                                      const UnitCalibrationOptions& options) {
  const std::string what = "unit calibration";
  if (!model.meta.arch.geometric_head) throw std::invalid_argument(what + ": the model's head is not geometric");
  SensorGeometryImpl& geometry = *model.net->geometry();
  UnitCalibrationReport report;
  report.images = static_cast<int>(images.size());
  std::vector<Eigen::Vector2d> targets = uncorrectedAngles(model, images);
  const geometric::Options solve = geometric::solveOptions(model);
  const geometric::Design design = geometric::designOf(geometry);
  report.before = design.mask;

  // Weights relative to the median spot's; the spot noise at that weight
  // scales the aperture prior against the data (as the baseline's fit).
  std::vector<GeometryObservation> obs = observe(design, images, targets, solve, 1.0);
  if (obs.size() < 3)
    throw std::invalid_argument(what + ": only " + std::to_string(obs.size()) +
                                " whole spots could be read in the images (need at least 3)");
  std::vector<double> weights;
  for (const auto& o : obs) weights.push_back(o.weight);
  std::nth_element(weights.begin(), weights.begin() + static_cast<std::ptrdiff_t>(weights.size() / 2), weights.end());
  const double weight_unit = weights[weights.size() / 2];
  for (auto& o : obs) o.weight /= weight_unit;
  const double prior2 = options.aperture_prior_um * options.aperture_prior_um;
  // Per aperture, the prior's weight for a gauge prior of `gauge`. A unit
  // calibrated before (recalibrated in flight) keeps its apertures' places
  // in the mask, which do not drift: each is held by its earlier variance
  // (over the spot noise at the median weight), which the new images refine.
  const auto aperturePriors = [&](double gauge) {
    std::vector<double> weights(static_cast<std::size_t>(design.mask.numApertures()), gauge);
    const std::vector<double>& earlier = model.meta.aperture_variance_um2;
    if (earlier.size() == weights.size())
      for (std::size_t k = 0; k < weights.size(); ++k)
        if (earlier[k] > 0.0) weights[k] = std::max(gauge, model.meta.spot_noise_um2 / weight_unit / earlier[k]);
    return weights;
  };

  GeometryFit first(design.mask, 0.0);
  Eigen::VectorXd p = first.start();
  report.spot_rms_um_before = weightedRms(first, p, obs);
  // First pass: the prior scaled by the starting geometry's residuals
  // (large: the unit is not that geometry), then re-read through the fitted
  // geometry, outliers (debris, ghosts on a spot, wrong references) dropped,
  // and refitted with the prior scaled by the fitted residuals.
  const double start_sigma = robustSigma(weightedNorms(first, p, obs));
  const GeometryFit coarse(design.mask, 0.0, aperturePriors(start_sigma * start_sigma / prior2));
  report.iterations += coarse.run(p, obs, options.max_iterations);
  geometric::Design fitted = design;
  fitted.mask = coarse.apply(p);
  // The angle correction and the spot bias change with the mask height: both at the coarse fit's.
  fitted.spot_bias = geometry.spotBiasAt(fitted.mask.height_um);
  targets = solvedTargets(model, images, fitted.mask);
  obs = observe(fitted, images, targets, solve, weight_unit);
  const std::vector<double> norms = weightedNorms(coarse, p, obs);
  const double sigma = std::max(robustSigma(norms), 1e-9);
  std::vector<GeometryObservation> inliers;
  for (std::size_t k = 0; k < obs.size(); ++k)
    if (norms[k] <= options.outlier_sigmas * sigma) inliers.push_back(obs[k]);
  report.outliers = static_cast<int>(obs.size() - inliers.size());
  if (inliers.size() < 3) throw std::invalid_argument(what + ": too few consistent spots in the images");
  // The prior holds an aperture to aperture_prior_um against the spot noise
  // of the fit itself (its residual variance per axis at unit weight),
  // refitted until the two agree. The coarse fit's residuals, re-read through
  // a geometry that moved, can be 45 times that variance: scaled by them, a
  // 20 um prior held wide_ma's unpinned apertures to 1-3 um and a 2 um one to
  // 0.1 um, which left 92 % of a unit's images model_mismatch.
  double prior_weight = sigma * sigma / prior2;
  GeometryFit fine(design.mask, 0.0, aperturePriors(prior_weight));
  report.iterations += fine.run(p, inliers, options.max_iterations);
  for (int pass = 0; pass < kPriorPasses; ++pass) {
    const double noise_weight = fine.residualVariance(p, inliers) / prior2;
    if (!(noise_weight > 0.0) || std::abs(noise_weight - prior_weight) <= 0.05 * prior_weight) break;
    prior_weight = noise_weight;
    fine = GeometryFit(design.mask, 0.0, aperturePriors(prior_weight));
    report.iterations += fine.run(p, inliers, options.max_iterations);
  }
  report.free_parameters = fine.freeParameters();
  report.spots = static_cast<int>(inliers.size());
  std::vector<bool> used(images.size(), false);
  for (const auto& o : inliers) used[static_cast<std::size_t>(o.sample)] = true;
  report.images_used = static_cast<int>(std::count(used.begin(), used.end(), true));
  report.image_used = used;
  report.spot_rms_um_after = weightedRms(fine, p, inliers);
  const Eigen::MatrixXd covariance = fine.covariance(p, inliers);
  report.standard_errors = GeometryFit::standardErrors(covariance);
  report.geometry_sigma_rad = geometrySigma(fine, p, covariance, design, images, targets, solve);
  const MaskGeometry fitted_mask = fine.apply(p);
  setHeadGeometry(model, fitted_mask);
  // Each aperture's position variance (its prior included), for the solve's weights.
  const std::vector<double> variance_um2 = fine.apertureVariances(p, inliers);
  model.meta.aperture_variance_um2 = variance_um2;
  model.meta.spot_noise_um2 = fine.residualVariance(p, inliers) * weight_unit;
  geometry.setPositionVariance(model.meta.aperture_variance_um2, model.meta.spot_noise_um2);
  for (double v : variance_um2) report.aperture_sigma_um.push_back(std::sqrt(v));
  model.meta.geometry_sigma_rad = report.geometry_sigma_rad;
  report.after = geometry.maskGeometry();
  return report;
}

std::array<double, 2> unitToleranceSigma(const Model& model, const TrainingSet& data, const AsBuiltConfig& tolerances) {
  requireGeometricHead(model, data, "unit tolerance sigma");
  const std::vector<UnitImage> images = readUnitImages(model, data, kSigmaImages);
  const geometric::Design design = geometric::designOf(*model.net->geometry());
  const auto draw = [&](Rng& rng) {
    MaskGeometry unit = design.mask;
    unit.height_um += tolerances.height_sigma_um * rng.normal();
    unit.offset_x_um += tolerances.offset_sigma_um * rng.normal();
    unit.offset_y_um += tolerances.offset_sigma_um * rng.normal();
    unit.rotation_rad += degToRad(tolerances.rotation_sigma_deg) * rng.normal();
    unit.tilt_x_rad += degToRad(tolerances.tilt_sigma_deg) * rng.normal();
    unit.tilt_y_rad += degToRad(tolerances.tilt_sigma_deg) * rng.normal();
    for (auto& a : unit.apertures_um)
      a += tolerances.aperture_position_sigma_um * Eigen::Vector2d(rng.normal(), rng.normal());
    return unit;
  };
  return solveChangeRms(design, images, uncorrectedAngles(model, images), geometric::solveOptions(model), draw, 1.0);
}

std::vector<UnitImage> readUnitImages(const Model& model, const std::vector<cv::Mat>& images,
                                      const std::vector<std::array<double, 2>>& reference_rad) {
  if (reference_rad.size() != images.size()) throw std::invalid_argument("readUnitImages: one reference per image");
  checkImages(images, model.meta.input);
  const std::vector<ImageRead> reads = readImages(
      model, images.size(),
      [&](std::size_t first, std::size_t last) {
        return encodeImages(
            {images.begin() + static_cast<std::ptrdiff_t>(first), images.begin() + static_cast<std::ptrdiff_t>(last)},
            model.meta.input);
      },
      [&](std::size_t i) { return reference_rad[i]; });
  std::vector<UnitImage> out;
  for (const auto& r : reads) out.push_back(r.image);
  return out;
}

std::vector<UnitImage> readUnitImages(const Model& model, const TrainingSet& data, std::size_t max_samples,
                                      std::vector<std::array<double, 2>>* estimates) {
  requireGeometricHead(model, data, "unit images");
  std::vector<UnitImage> out;
  for (const ImageRead& r : readSamples(model, evenlySpaced(data, max_samples))) {
    out.push_back(r.image);
    if (estimates) estimates->push_back({r.prediction.alpha_rad, r.prediction.beta_rad});
  }
  return out;
}

UnitCalibrationReport calibrateUnit(Model& model, const TrainingSet& data, const std::string& data_description,
                                    const UnitCalibrationOptions& options) {
  const std::string what = "unit calibration";
  requireGeometricHead(model, data, what);
  const std::vector<const SparseSample*> samples = evenlySpaced(data, options.max_samples);
  const std::vector<ImageRead> reads = readSamples(model, samples);
  if (reads.empty()) throw std::invalid_argument(what + ": no image has a lit pixel");
  std::vector<UnitImage> images;
  for (const auto& r : reads) images.push_back(r.image);
  const double before_deg = angleRmsDeg(reads);
  UnitCalibrationReport report = fitUnitGeometry(model, images, options);
  report.images = static_cast<int>(samples.size());
  for (std::size_t k = 0; k < reads.size(); ++k)
    if (report.image_used[k]) report.whole_spot_samples.push_back(samples[reads[k].input]);
  report.angle_rms_deg_before = before_deg;
  report.angle_rms_deg_after = angleRmsDeg(readSamples(model, samples));
  // The unit's own images widen the input envelope: its lit-pixel counts may
  // lie past the family's, which refused 1-7 % of a calibrated unit's images
  // as out_of_distribution. Only those with a whole spot in the fit: an
  // image whose only spot the edge cuts may hold its flank alone (a 3x
  // thesis_sa unit 44 um off centre: read up to 0.5 deg off), which the
  // family's envelope refuses.
  std::vector<int> whole_counts;
  for (const SparseSample* s : report.whole_spot_samples)
    whole_counts.push_back(data.siteCount(*s, model.meta.input.max_sites));
  if (!whole_counts.empty())
    recordInputEnvelope(model.meta, covering(inputEnvelopeOf(model.meta), measureInputEnvelope(whole_counts)));
  YAML::Node record = YAML::Load(report.toYaml());
  record["data"] = data_description;
  model.meta.unit_yaml = YAML::Dump(record);
  return report;
}

MismatchCalibration calibrateSpotMismatch(Model& model, const TrainingSet& data, std::size_t max_samples,
                                          double threshold_factor) {
  const std::string what = "spot mismatch calibration";
  requireGeometricHead(model, data, what);
  std::vector<double> values;
  for (const ImageRead& r : readSamples(model, evenlySpaced(data, max_samples)))
    if (r.residual_per_dof > 0.0) values.push_back(r.residual_per_dof);
  if (values.empty()) throw std::invalid_argument(what + ": no image shows two spots");
  std::sort(values.begin(), values.end());
  MismatchCalibration c;
  c.samples = values.size();
  c.level = values[values.size() / 2];
  const std::size_t high = std::min(values.size() - 1, static_cast<std::size_t>(0.995 * values.size()));
  c.threshold = threshold_factor * values[high] / c.level;
  std::size_t flagged = 0;
  for (double v : values) flagged += v / c.level > c.threshold;
  c.flagged_fraction = static_cast<double>(flagged) / static_cast<double>(values.size());
  model.meta.mismatch_level = c.level;
  model.meta.mismatch_threshold = c.threshold;
  return c;
}

}  // namespace dss
