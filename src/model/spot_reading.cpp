// The spot read-out per image: centroid weights, the weighted centroid and,
// for lattice masks, the phase of the whole spots modulo the pitch.
#include <torch/nn/functional/activation.h>
#include <torch/nn/functional/conv.h>
#include <torch/nn/functional/pooling.h>

#include <algorithm>
#include <cmath>

#include "digital_sun_sensor/model/sscnn.h"
#include "digital_sun_sensor/sparse/ops.h"
#include "lattice_code.h"

namespace dss {

using sparse::RulebookCache;
using sparse::SparseTensor;
namespace F = torch::nn::functional;

torch::Tensor SscnnNetImpl::centroidWeights(const torch::Tensor& logits, const torch::Tensor& raw_value) const {
  const torch::Tensor value =
      arch_.value_saturation > 0.0 ? raw_value / (1.0 + arch_.value_saturation * raw_value) : raw_value;
  if (arch_.centroid_weighting == CentroidWeighting::kIntensity) return value;
  const torch::Tensor learned = torch::softplus(logits);  // log(2) where the branch outputs 0 (its start)
  if (arch_.centroid_weighting == CentroidWeighting::kLearned) return learned;
  return value * learned * (1.0 / std::log(2.0));
}

SscnnNetImpl::SpotReading SscnnNetImpl::readSpots(const torch::Tensor& w, const torch::Tensor& xy,
                                                  const torch::Tensor& lit, const torch::Tensor& index,
                                                  std::int64_t batch) const {
  auto weighted_sum = [&](const torch::Tensor& values) { return sparse::indexSum(values, index, batch); };
  SpotReading reading;
  reading.centroid = weighted_sum(w * xy) / (weighted_sum(w) + 1e-6);
  if (!arch_.latticeHead()) return reading;
  const torch::Tensor pitch = torch::tensor({arch_.lattice_pitch_x, arch_.lattice_pitch_y}, xy.options());
  // Phase of the spot positions modulo the pitch: a circular mean, the same
  // whichever spots are on the detector (exact for symmetric spots). Also the
  // total weight per image.
  auto circularMean = [&](const torch::Tensor& weights) {
    const torch::Tensor angle = xy * (2.0 * M_PI / pitch);
    const torch::Tensor sums = weighted_sum(torch::cat({weights * torch::cos(angle), weights * torch::sin(angle)}, 1));
    return std::make_pair(torch::atan2(sums.slice(1, 2, 4), sums.slice(1, 0, 2)) * pitch / (2.0 * M_PI),
                          weighted_sum(weights));
  };
  reading.phase = circularMean(w).first;
  if (arch_.lattice_whole_spot_phase) {
    torch::Tensor whole;  // [N, 1]: the factor of the site's weight in the phase, 0 where its spot is cut
    {
      torch::NoGradGuard no_grad;
      const torch::Tensor site_phase = reading.phase.detach().index_select(0, index);
      const torch::Tensor cell = ((xy.detach() - site_phase) / pitch).round();
      if (arch_.lattice_spotwise_phase) {
        whole = spotwisePhaseFactors(w.detach(), xy.detach(), lit, index, cell);
      } else {
        const torch::Tensor spot_centre = site_phase + cell * pitch;
        whole = (spot_centre.abs() < 1.0 - arch_.wholeSpotMargin()).all(1, true).to(w.scalar_type());
      }
    }
    const auto [whole_phase, whole_weight] = circularMean(w * whole);
    // An image without a whole spot keeps the phase of all its spots.
    reading.phase = torch::where(whole_weight > 1e-6, whole_phase, reading.phase);
  }
  if (lattice_log_area_.defined()) {
    LatticeCode code;
    code.pitch_x = arch_.lattice_pitch_x;
    code.pitch_y = arch_.lattice_pitch_y;
    code.columns = arch_.lattice_columns;
    code.rows = arch_.lattice_rows;
    code.log_area = lattice_log_area_;
    code.edge_margin = arch_.wholeSpotMargin();
    if (geometric_prior_.defined()) {
      code.max_shift_x = geometric_prior_extent_[0].item<double>();
      code.max_shift_y = geometric_prior_extent_[1].item<double>();
    }
    const CodePlacement placement = codeLatticePlacement(code, reading.phase, xy, lit, index, batch);
    reading.code_steps = placement.steps;
    reading.code_margin = placement.margin;
  } else if (arch_.lattice_resolve == LatticeResolve::kCentroid) {
    for (int axis = 0; axis < 2; ++axis)
      reading.contradictions[axis] = axisContradictions(
          arch_.latticePitch(axis), arch_.latticeCount(axis), arch_.wholeSpotMargin(), kMinSpotSites,
          reading.phase.select(1, axis), latticeSteps(axis, xy.options()), xy.select(1, axis), lit, index, batch);
  }
  return reading;
}

torch::Tensor SscnnNetImpl::spotwisePhaseFactors(const torch::Tensor& w, const torch::Tensor& xy,
                                                 const torch::Tensor& lit, const torch::Tensor& index,
                                                 const torch::Tensor& cell) const {
  // A spot is the lit sites of one image in one lattice cell around the phase.
  const auto span =
      static_cast<std::int64_t>(2 * std::ceil(1.0 / std::min(arch_.lattice_pitch_x, arch_.lattice_pitch_y) + 2.0) + 1);
  const torch::Tensor cells = cell.to(torch::kLong) + span / 2;
  const torch::Tensor key = (index * span + cells.select(1, 0)) * span + cells.select(1, 1);
  const auto unique = torch::_unique(key, /*sorted=*/false, /*return_inverse=*/true);
  const torch::Tensor& spot = std::get<1>(unique);  // the site's spot, 0 .. spots - 1
  const std::int64_t spots = std::get<0>(unique).size(0);
  auto per_spot = [&](const torch::Tensor& values) { return sparse::indexSum(values, spot, spots); };
  const torch::Tensor sum_w = per_spot(w).clamp_min(1e-12);
  const torch::Tensor mean = per_spot(w * xy) / sum_w;
  const torch::Tensor spread = (per_spot(w * xy * xy) / sum_w - mean * mean).sum(1, true);  // s^2
  // Inverse spread in pixel units; a spot of one pixel has that pixel's own spread.
  const double px = arch_.lattice_pixel_x, py = arch_.lattice_pixel_y;
  torch::Tensor factor = (px * py) / spread.clamp_min((px * px + py * py) / 12.0);
  // Cut: a lit site on the detector's outermost row or column (|coordinate| = 1 - pixel / 2).
  const torch::Tensor limit = torch::tensor({1.0 - px, 1.0 - py}, xy.options());
  const torch::Tensor on_edge = (xy.abs() > limit).any(1, true).to(w.scalar_type()) * lit.view({-1, 1});
  factor = torch::where(per_spot(on_edge) > 0, torch::zeros_like(factor), factor);
  return factor.index_select(0, spot);
}

}  // namespace dss
