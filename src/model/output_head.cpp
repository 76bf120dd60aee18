// The output head: angles (prior + polynomial of the position + feature
// corrections), log variance and class logits from the pooled features and
// the spot reading; the variance level behind its own interface.
#include <torch/nn/functional/activation.h>
#include <torch/nn/functional/conv.h>
#include <torch/nn/functional/pooling.h>

#include <algorithm>
#include <cmath>

#include "digital_sun_sensor/model/sscnn.h"
#include "digital_sun_sensor/sparse/ops.h"

namespace dss {

using sparse::RulebookCache;
using sparse::SparseTensor;
namespace F = torch::nn::functional;

// x^i y^j for 1 <= i + j <= degree: a polynomial map from the spot centroid to
// the angles absorbs the pinhole's atan and smooth distortions, which an MLP
// would have to learn to 1e-4 of the field of view.
torch::Tensor SscnnNetImpl::monomials(const torch::Tensor& centroid) const {
  const auto x = centroid.slice(1, 0, 1), y = centroid.slice(1, 1, 2);
  std::vector<torch::Tensor> terms;
  for (int degree = 1; degree <= arch_.centroid_degree; ++degree)
    for (int j = 0; j <= degree; ++j) terms.push_back(x.pow(degree - j) * y.pow(j));
  return torch::cat(terms, 1);
}

SscnnOutput SscnnNetImpl::head(const torch::Tensor& pooled, const SpotReading& spots,
                               const torch::Tensor& known_classes) {
  // Pooled features of a network without batch norm grow with depth and
  // brightness; normalized, the MLP starts in its working range.
  const torch::Tensor normed = head_norm_->forward(pooled);
  SscnnOutput result;
  const bool class_resolved = arch_.apertureClassLattice();
  torch::Tensor position = spots.centroid;
  if (spots.phase.defined() && !class_resolved) position = resolveLattice(spots, {}, {});
  // The class branch reads the position when it is known before the class,
  // else the coarse centroid and the lattice phase (as cos, sin).
  torch::Tensor class_in = position.defined() ? torch::cat({normed, position}, 1) : normed;
  if (class_resolved) {
    const auto turns =
        spots.phase *
        torch::tensor({2.0 * M_PI / arch_.lattice_pitch_x, 2.0 * M_PI / arch_.lattice_pitch_y}, spots.phase.options());
    class_in = torch::cat({class_in, torch::cos(turns), torch::sin(turns)}, 1);
  }
  result.class_logits = class_output_->forward(torch::silu(class_hidden_->forward(class_in)));
  result.code_margin = spots.code_margin;
  if (class_resolved) {
    position = resolveLattice(spots, result.class_logits, known_classes);
    // The class that goes with the position: the aperture whose spot is
    // nearest the detector centre (the classifier only had to be right to
    // half a pitch).
    torch::NoGradGuard no_grad;
    const auto spot_positions = position.detach().unsqueeze(1) + lattice_class_offsets_.unsqueeze(0);  // [B, C, 2]
    result.resolved_class = spot_positions.pow(2).sum(2).argmin(1);
  }
  torch::Tensor h = position.defined() ? torch::cat({normed, position}, 1) : normed;
  for (auto& layer : mlp_) h = torch::silu(layer->forward(h));
  if (arch_.feature_corrections) result.angles = arch_.residual_scale * output_->forward(h);
  if (position.defined()) {
    const torch::Tensor smooth =
        priorAngles(position) + arch_.residual_scale * centroid_skip_->forward(monomials(position));
    result.angles = result.angles.defined() ? result.angles + smooth : smooth;
  }
  // The geometric head reads the variance once its solve is known.
  if (arch_.geometric_head)
    result.head_features = h.detach();
  else
    result.log_variance = variance_->forward(h.detach());
  return result;
}

void SscnnNetImpl::solveAngles(SscnnOutput& out, const torch::Tensor& w, const torch::Tensor& xy,
                               const torch::Tensor& index, std::int64_t batch, const torch::Tensor& known_angles) {
  const double scale = arch_.angle_scale_rad;
  out.coarse_angles = out.angles;
  const torch::Tensor reference = (known_angles.defined() ? known_angles : out.angles).detach().to(torch::kFloat64);
  const double half_width_um = 0.5 * arch_.detector_width_px * arch_.detector_pitch_um;
  const double half_height_um = 0.5 * arch_.detector_height_px * arch_.detector_pitch_um;
  const torch::Tensor site_um =
      xy.to(torch::kFloat64) * torch::tensor({half_width_um, half_height_um}, torch::kFloat64).view({1, 2});
  GeometricSolveOptions options;
  options.gate_um = arch_.geometric_gate_um;
  options.pitch_um = arch_.detector_pitch_um;
  options.width_px = arch_.detector_width_px;
  options.height_px = arch_.detector_height_px;
  options.symmetric_spots = arch_.geometric_symmetric_spots;
  // An aperture-code coarse estimate has the association right already: on
  // wide_ma the search changed no estimate and took 43 of 49 ms per image.
  options.search_reference = !known_angles.defined() && !arch_.latticeHead();
  const GeometricSolution solution =
      solveGeometry(*geometry_, site_um, w.reshape({-1}), index, batch, reference * scale, options);
  // The geometry's angles plus a smooth learned correction (what the
  // nominal geometry leaves: diffraction and vignetting shifts, a mask
  // thickness), in the network's precision.
  const torch::Tensor corrected = correctSolvedAngles((solution.angles_rad / scale).to(out.angles.scalar_type()));
  const torch::Tensor read = (solution.spots_read > 0).view({-1, 1});
  out.angles = torch::where(read, corrected, out.coarse_angles);
  // The solve's variance per unit weight (normalized; 0 where no spot was
  // read) beside the features: the variance head weighs both, and the sigma
  // interface (a constant, a factor) holds as for the other heads.
  const torch::Tensor solve_log_variance = (solution.log_variance - 2.0 * std::log(scale)).to(out.angles.scalar_type());
  out.log_variance = variance_->forward(torch::cat(
      {out.head_features, torch::where(read, solve_log_variance, torch::zeros_like(solve_log_variance))}, 1));
  out.spots_read = solution.spots_read;
  out.solve_residual_um = solution.residual_um;
  out.solve_residual_per_dof = solution.residual_per_dof;
  out.lone_spot_ambiguous = solution.lone_spot_ambiguous;
  out.solve_site_um = site_um.detach();
  out.solve_site_weight = w.detach().reshape({-1}).to(torch::kFloat64);
  out.solve_site_image = index;
  torch::NoGradGuard no_grad;
  const torch::Tensor angles_rad = out.angles.detach().to(torch::kFloat64) * scale;
  if (arch_.geometric_class_by_aperture) {
    out.resolved_class = geometry_->spotsUm(angles_rad).pow(2).sum(2).argmin(1);
  } else {
    const auto alpha = angles_rad.select(1, 0), beta = angles_rad.select(1, 1);
    out.resolved_class = (alpha >= 0).to(torch::kLong) + 2 * (beta >= 0).to(torch::kLong);
  }
}

torch::Tensor SscnnNetImpl::correctSolvedAngles(const torch::Tensor& solved) {
  return solved + arch_.residual_scale * geometric_correction_->forward(monomials(solved.detach()));
}

void SscnnNetImpl::shiftLogVariance(double alpha, double beta) {
  torch::NoGradGuard no_grad;
  variance_->bias[0] += alpha;
  variance_->bias[1] += beta;
}

void SscnnNetImpl::setConstantLogVariance(double alpha, double beta) {
  torch::NoGradGuard no_grad;
  variance_->weight.zero_();
  variance_->bias[0] = alpha;
  variance_->bias[1] = beta;
}

std::optional<std::array<double, 2>> SscnnNetImpl::constantLogVariance() const {
  if (variance_->weight.count_nonzero().item<std::int64_t>() != 0) return std::nullopt;
  return std::array<double, 2>{variance_->bias[0].item<double>(), variance_->bias[1].item<double>()};
}

}  // namespace dss
