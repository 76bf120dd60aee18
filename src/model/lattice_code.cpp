#include "lattice_code.h"

#include <torch/torch.h>

#include <cmath>
#include <stdexcept>

#include "digital_sun_sensor/sparse/ops.h"

namespace dss {
namespace {

// The lattice index of the aperture whose spot each cell holds, for each
// candidate step [K, C] (not clamped): cell c (in pitches from the phase)
// holds aperture c - step + (count - 1) / 2 when the lattice centre's spot
// is at the phase plus `step` pitches (an even count's half pitch included).
torch::Tensor apertureAt(const torch::Tensor& steps, const torch::Tensor& cell_offsets, int count) {
  return (cell_offsets.unsqueeze(0) - steps.unsqueeze(1) + 0.5 * (count - 1)).round();
}

// One axis of the placement search: cells -reach..reach around the phase, and
// candidate steps k (lattice centre at phase + (k + half) pitch).
struct AxisPlan {
  double pitch, half;
  std::int64_t reach, cells, candidates;
  torch::Tensor cell_offsets;  // [cells] in pitches
  torch::Tensor steps;         // [candidates] in pitches, half included
  torch::Tensor aperture;      // [candidates, cells] lattice index of the aperture a cell's spot comes from
  torch::Tensor in_array;      // [candidates, cells]

  AxisPlan(double pitch_norm, int count) : pitch(pitch_norm), half(count % 2 == 0 ? 0.5 : 0.0) {
    reach = static_cast<std::int64_t>(std::ceil(1.0 / pitch)) + 1;
    cells = 2 * reach + 1;
    const std::int64_t step_reach = reach + count;
    candidates = 2 * step_reach + 1;
    const auto real = torch::TensorOptions().dtype(torch::kDouble);
    cell_offsets = torch::arange(-reach, reach + 1, real);
    steps = torch::arange(-step_reach, step_reach + 1, real) + half;
    aperture = apertureAt(steps, cell_offsets, count).to(torch::kLong);
    in_array = (aperture >= 0) & (aperture < count);
    aperture = aperture.clamp(0, count - 1);
  }
};

}  // namespace

CodePlacement codeLatticePlacement(const LatticeCode& code, const torch::Tensor& phase, const torch::Tensor& xy,
                                   const torch::Tensor& lit, const torch::Tensor& index, std::int64_t batch) {
  if (!code.log_area.defined() || code.log_area.size(0) != code.rows || code.log_area.size(1) != code.columns)
    throw std::invalid_argument("codeLatticePlacement: log_area must be [rows, columns]");
  torch::NoGradGuard no_grad;
  const AxisPlan ax(code.pitch_x, code.columns), ay(code.pitch_y, code.rows);
  const auto phase_d = phase.detach().to(torch::kDouble);

  // Per cell [B, 1, 1, cells_y, cells_x]: lit sites and their variance along
  // x and y (the spot's size: a Fresnel ring or a disk, it grows with the
  // aperture; unlike the lit area, it does not depend on the exposure).
  const auto xy_d = xy.detach().to(torch::kDouble);
  const auto rel = (xy_d - phase_d.index_select(0, index)) / torch::tensor({ax.pitch, ay.pitch}, phase_d.options());
  const auto cx = rel.select(1, 0).round().to(torch::kLong).clamp(-ax.reach, ax.reach) + ax.reach;
  const auto cy = rel.select(1, 1).round().to(torch::kLong).clamp(-ay.reach, ay.reach) + ay.reach;
  const auto flat = (index * ay.cells + cy) * ax.cells + cx;
  const auto l = lit.detach().reshape({-1, 1}).to(torch::kDouble);
  const auto offset = rel - rel.round();  // within the cell, in pitches
  const auto sums =
      sparse::indexSum(torch::cat({l, l * offset, l * offset.pow(2)}, 1), flat, batch * ay.cells * ax.cells)
          .view({batch, 1, 1, ay.cells, ax.cells, 5});
  const auto area = sums.select(5, 0);
  const auto n = area.clamp_min(1.0);
  const auto spread_x = sums.select(5, 3) / n - (sums.select(5, 1) / n).pow(2);
  const auto spread_y = sums.select(5, 4) / n - (sums.select(5, 2) / n).pow(2);

  // Cells whose spot is not cut across x (y), [B, 1, 1, cells_y, cells_x]:
  // their x (y) spread is the spot's, provided that the spot's centre is on
  // the detector (a spot cut along a chord through its centre or nearer its
  // edge keeps about its spread along the cut).
  auto within = [&](const AxisPlan& a, int axis, double margin) {
    const auto centre = phase_d.select(1, axis).unsqueeze(1) + a.cell_offsets.unsqueeze(0) * a.pitch;  // [B, cells]
    return centre.abs() < 1.0 - margin;
  };
  const std::vector<std::int64_t> shape{batch, 1, 1, ay.cells, ax.cells};
  auto grid = [&](const torch::Tensor& along_y, const torch::Tensor& along_x) {
    return (along_y.unsqueeze(2) & along_x.unsqueeze(1)).reshape(shape);
  };
  const auto whole = grid(within(ay, 1, code.edge_margin), within(ax, 0, code.edge_margin));
  const auto spread_x_valid = grid(within(ay, 1, 0.0), within(ax, 0, code.edge_margin));
  const auto spread_y_valid = grid(within(ay, 1, code.edge_margin), within(ax, 0, 0.0));

  // Per placement [candidates_y, candidates_x, cells_y, cells_x]: the aperture
  // each cell would see, and whether there is one.
  const auto ia = ay.aperture.view({ay.candidates, 1, ay.cells, 1});
  const auto ja = ax.aperture.view({1, ax.candidates, 1, ax.cells});
  const auto expected = code.log_area.to(torch::kDouble).index({ia, ja}).unsqueeze(0);
  const auto in_array =
      (ay.in_array.view({ay.candidates, 1, ay.cells, 1}) & ax.in_array.view({1, ax.candidates, 1, ax.cells}))
          .unsqueeze(0);

  const auto lit_cell = area >= static_cast<double>(code.min_spot_sites);
  const auto contradictions = ((lit_cell & ~in_array) | (~lit_cell & whole & in_array)).sum({3, 4});
  // Spread along an axis wherever the spot is not cut across it, about a
  // free level per axis (oblique light stretches every spot alike).
  auto misfit = [&](const torch::Tensor& spread_axis, const torch::Tensor& valid) {
    const auto used = (lit_cell & valid & in_array).to(torch::kDouble);
    const auto residual = spread_axis.clamp_min(1e-12).log() - expected;
    const auto mean = (used * residual).sum({3, 4}, true) / used.sum({3, 4}, true).clamp_min(1.0);
    return (used * (residual - mean).pow(2)).sum({3, 4});  // [B, Ky, Kx]
  };
  const auto size_misfit = misfit(spread_x, spread_x_valid) + misfit(spread_y, spread_y_valid);

  // The lattice centre must stay where the field of view can put it.
  auto outside = [&](const AxisPlan& a, int axis, double max_shift) {
    return (phase_d.select(1, axis).unsqueeze(1) + a.steps.unsqueeze(0) * a.pitch).abs() > max_shift;  // [B, K]
  };
  const auto out_of_field =
      outside(ay, 1, code.max_shift_y).unsqueeze(2) | outside(ax, 0, code.max_shift_x).unsqueeze(1);

  const auto score = out_of_field.to(torch::kDouble) * 1e6 + contradictions.to(torch::kDouble) * 1e3 + size_misfit;
  const auto flat_score = score.view({batch, -1});
  const auto best = flat_score.argmin(1);
  const auto lowest = std::get<0>(flat_score.topk(2, 1, /*largest=*/false));  // [B, 2], ascending
  const auto step_x = ax.steps.index_select(0, best.remainder(ax.candidates)) * ax.pitch;
  const auto step_y = ay.steps.index_select(0, best.div(ax.candidates, "floor")) * ay.pitch;
  // A small floor keeps a tie of two perfect fits (e.g. one usable spot per axis) at a margin of 1.
  constexpr double kScoreFloor = 1e-3;
  return {torch::stack({step_x, step_y}, 1).to(phase.scalar_type()),
          (lowest.select(1, 1) + kScoreFloor) / (lowest.select(1, 0) + kScoreFloor)};
}

torch::Tensor axisContradictions(double pitch, int count, double edge_margin, int min_spot_sites,
                                 const torch::Tensor& phase, const torch::Tensor& steps, const torch::Tensor& position,
                                 const torch::Tensor& lit, const torch::Tensor& index, std::int64_t batch) {
  torch::NoGradGuard no_grad;
  const auto real = torch::TensorOptions().dtype(torch::kDouble);
  const auto phase_d = phase.detach().to(torch::kDouble).reshape({-1});
  const auto reach = static_cast<std::int64_t>(std::ceil(1.0 / pitch)) + 1;
  const std::int64_t cells = 2 * reach + 1;
  const auto rel = (position.detach().to(torch::kDouble).reshape({-1}) - phase_d.index_select(0, index)) / pitch;
  const auto cell = rel.round().to(torch::kLong).clamp(-reach, reach) + reach;
  const auto lit_sites = torch::zeros({batch * cells}, real)
                             .index_add_(0, index * cells + cell, lit.detach().reshape({-1}).to(torch::kDouble))
                             .view({batch, 1, cells});
  const auto lit_cell = lit_sites >= static_cast<double>(min_spot_sites);  // [B, 1, C]
  const auto offsets = torch::arange(-reach, reach + 1, real);             // [C], pitches
  const auto whole = ((phase_d.unsqueeze(1) + offsets.unsqueeze(0) * pitch).abs() < 1.0 - edge_margin).unsqueeze(1);
  const auto aperture = apertureAt(steps.detach().to(torch::kDouble).reshape({-1}) / pitch, offsets, count);
  const auto in_array = ((aperture >= 0) & (aperture < count)).unsqueeze(0);  // [1, K, C]
  return ((lit_cell & ~in_array) | (~lit_cell & whole & in_array)).sum(2).to(phase.scalar_type());
}

}  // namespace dss
