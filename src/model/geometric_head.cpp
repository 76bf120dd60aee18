#include "digital_sun_sensor/model/geometric_head.h"

#include <torch/torch.h>

#include <stdexcept>
#include <string>

namespace dss {
namespace {

const auto kDouble = torch::TensorOptions().dtype(torch::kFloat64);

// R = R_y(tilt_y) R_x(tilt_x) R_z(rotation), as the simulator's maskRotation.
torch::Tensor maskRotation(const torch::Tensor& rotation, const torch::Tensor& tilt) {
  const auto zero = torch::zeros({1}, kDouble), one = torch::ones({1}, kDouble);
  const auto cz = torch::cos(rotation), sz = torch::sin(rotation);
  const auto cx = torch::cos(tilt.slice(0, 0, 1)), sx = torch::sin(tilt.slice(0, 0, 1));
  const auto cy = torch::cos(tilt.slice(0, 1, 2)), sy = torch::sin(tilt.slice(0, 1, 2));
  const auto rz =
      torch::stack({torch::cat({cz, -sz, zero}), torch::cat({sz, cz, zero}), torch::cat({zero, zero, one})});
  const auto rx =
      torch::stack({torch::cat({one, zero, zero}), torch::cat({zero, cx, -sx}), torch::cat({zero, sx, cx})});
  const auto ry =
      torch::stack({torch::cat({cy, zero, sy}), torch::cat({zero, one, zero}), torch::cat({-sy, zero, cy})});
  return ry.matmul(rx).matmul(rz);
}

// Per image and aperture: the summed weight [B*K], the weighted centroid
// [B*K, 2] and the weighted spread s^2 [B*K] of the sites assigned to it
// (spot = index * K + aperture), and whether a site of it lies on the
// detector's outermost rows or columns [B*K].
struct SpotReads {
  torch::Tensor sum, centroid, spread, cut;
};

SpotReads readSpots(const torch::Tensor& site_um, const torch::Tensor& weight, const torch::Tensor& on_edge,
                    const torch::Tensor& spot, std::int64_t spots) {
  SpotReads r;
  auto per_spot = [&](const torch::Tensor& values) {
    return torch::zeros({spots, values.size(1)}, values.options()).index_add(0, spot, values);
  };
  const auto w = weight.view({-1, 1});
  r.sum = per_spot(w).view({-1});
  const auto safe = r.sum.clamp_min(1e-30).view({-1, 1});
  r.centroid = per_spot(w * site_um) / safe;
  r.spread = (per_spot(w * site_um * site_um) / safe - r.centroid * r.centroid).sum(1);
  r.cut = per_spot(on_edge.view({-1, 1}).to(torch::kFloat64)).view({-1}) > 0;
  return r;
}

// Angles [R, 2] that put group `group` [R]'s spot at target [R, 2] (um):
// Newton from normal incidence, Jacobians by central differences.
torch::Tensor invertGroups(const SensorGeometryImpl& geometry, const torch::Tensor& group,
                           const torch::Tensor& target) {
  auto spotOf = [&](const torch::Tensor& angles) {  // [R, 2]
    return geometry.groupSpotsUm(angles).gather(1, group.view({-1, 1, 1}).expand({-1, 1, 2})).squeeze(1);
  };
  torch::Tensor angles = torch::zeros_like(target);
  constexpr double kStep = 1e-6;
  for (int it = 0; it < 6; ++it) {
    std::vector<torch::Tensor> columns;
    for (int axis = 0; axis < 2; ++axis) {
      auto delta = torch::zeros({1, 2}, kDouble);
      delta[0][axis] = kStep;
      columns.push_back((spotOf(angles + delta) - spotOf(angles - delta)) / (2.0 * kStep));
    }
    const auto j = torch::stack(columns, 2);  // [R, 2, 2]
    const auto r = target - spotOf(angles);
    const auto det = j.select(1, 0).select(1, 0) * j.select(1, 1).select(1, 1) -
                     j.select(1, 0).select(1, 1) * j.select(1, 1).select(1, 0);
    const auto safe = torch::where(det.abs() > 1e-12, det, torch::ones_like(det));
    const auto dx =
        (j.select(1, 1).select(1, 1) * r.select(1, 0) - j.select(1, 0).select(1, 1) * r.select(1, 1)) / safe;
    const auto dy =
        (j.select(1, 0).select(1, 0) * r.select(1, 1) - j.select(1, 1).select(1, 0) * r.select(1, 0)) / safe;
    angles = (angles + torch::stack({dx, dy}, 1)).clamp(-1.4, 1.4);
  }
  return angles;
}

}  // namespace

SensorGeometryImpl::SensorGeometryImpl(int apertures, int groups) : group_count_(groups) {
  if (apertures < 1 || groups < 1 || groups > apertures)
    throw std::invalid_argument("sensor geometry: needs at least one aperture and 1..apertures groups");
  height_um = register_buffer("height_um", torch::ones({1}, kDouble));
  offset_um = register_buffer("offset_um", torch::zeros({2}, kDouble));
  rotation_rad = register_buffer("rotation_rad", torch::zeros({1}, kDouble));
  tilt_rad = register_buffer("tilt_rad", torch::zeros({2}, kDouble));
  apertures_um = register_buffer("apertures_um", torch::zeros({apertures, 2}, kDouble));
  glass_thickness_um = register_buffer("glass_thickness_um", torch::zeros({1}, kDouble));
  glass_index = register_buffer("glass_index", torch::ones({1}, kDouble));
  aperture_group = register_buffer("aperture_group", torch::arange(apertures, torch::kLong).clamp_max(groups - 1));
  aperture_flux = register_buffer("aperture_flux", torch::ones({apertures}, kDouble));
}

void SensorGeometryImpl::setDesign(const GeometryDesign& design) {
  const auto count = static_cast<std::size_t>(apertures());
  auto fail = [](const std::string& what) { throw std::invalid_argument("sensor geometry: " + what); };
  if (design.apertures_um.size() != count)
    fail(std::to_string(design.apertures_um.size()) + " apertures for a model of " + std::to_string(count));
  if (!design.groups.empty() && design.groups.size() != count) fail("one group per aperture");
  if (!design.fluxes.empty() && design.fluxes.size() != count) fail("one flux per aperture");
  if (!(design.height_um > 0.0) || !(design.glass_index >= 1.0) || !(design.glass_thickness_um >= 0.0))
    fail("height must be positive, glass thickness >= 0 and index >= 1");
  std::vector<bool> used(static_cast<std::size_t>(group_count_), false);
  for (std::size_t k = 0; k < count; ++k) {
    const int g = design.groups.empty() ? static_cast<int>(k) : design.groups[k];
    if (g < 0 || g >= group_count_)
      fail("aperture " + std::to_string(k) + " in group " + std::to_string(g) + " of " + std::to_string(group_count_));
    used[static_cast<std::size_t>(g)] = true;
    if (!design.fluxes.empty() && !(design.fluxes[k] > 0.0)) fail("fluxes must be positive");
  }
  for (std::size_t g = 0; g < used.size(); ++g)
    if (!used[g]) fail("group " + std::to_string(g) + " has no aperture");
  torch::NoGradGuard no_grad;
  height_um.fill_(design.height_um);
  offset_um.zero_();
  rotation_rad.zero_();
  tilt_rad.zero_();
  for (std::size_t k = 0; k < count; ++k) {
    const auto row = static_cast<std::int64_t>(k);
    for (int axis = 0; axis < 2; ++axis)
      apertures_um[row][axis] = design.apertures_um[k][static_cast<std::size_t>(axis)];
    aperture_group[row] = design.groups.empty() ? row : design.groups[k];
    aperture_flux[row] = design.fluxes.empty() ? 1.0 : design.fluxes[k];
  }
  glass_thickness_um.fill_(design.glass_thickness_um);
  glass_index.fill_(design.glass_index);
}

torch::Tensor SensorGeometryImpl::spotsUm(const torch::Tensor& angles_rad) const {
  const auto apertures = apertures_um.size(0);
  const auto mask_frame = torch::cat({apertures_um, torch::zeros({apertures, 1}, kDouble)}, 1);  // [K, 3]
  const auto centres = mask_frame.matmul(maskRotation(rotation_rad, tilt_rad).t()) +
                       torch::cat({offset_um, height_um}).unsqueeze(0);  // [K, 3], exit face
  const auto z = centres.select(1, 2);
  // A mask lower than the glass (a large negative height error) rests on a
  // thinner slab: the glass never extends above the aperture.
  const auto glass = torch::minimum(glass_thickness_um.expand_as(z), z);
  const auto air = z - glass;
  // The light travels along -s, s ~ (tan alpha, tan beta, 1): lateral drift
  // per unit drop s_xy / s_z in air; in glass tan(refracted) along s_xy.
  const auto t = torch::tan(angles_rad).unsqueeze(1);  // [B, 1, 2]
  const auto norm2 = 1.0 + t.pow(2).sum(2, true);      // [B, 1, 1]
  const auto sin2_glass = (t.pow(2).sum(2, true) / norm2) / glass_index.pow(2);
  const auto glass_drift = t / (glass_index * norm2.sqrt() * (1.0 - sin2_glass).sqrt());
  return centres.slice(1, 0, 2).unsqueeze(0) - air.view({1, -1, 1}) * t - glass.view({1, -1, 1}) * glass_drift;
}

torch::Tensor SensorGeometryImpl::groupSpotsUm(const torch::Tensor& angles_rad) const {
  const auto spots = spotsUm(angles_rad);
  if (group_count_ == apertures()) return spots;
  const auto flux = aperture_flux.view({1, -1, 1});
  const auto sum = torch::zeros({group_count_}, kDouble).index_add(0, aperture_group, aperture_flux);
  return torch::zeros({spots.size(0), group_count_, 2}, kDouble).index_add(1, aperture_group, spots * flux) /
         sum.view({1, -1, 1});
}

namespace {

// The solve's steps over one set of sites (positions [N, 2] um, image index
// [N] of `batch` images): association, spot weights, Gauss-Newton.
class Solver {
 public:
  Solver(const SensorGeometryImpl& geometry, torch::Tensor sites, torch::Tensor index, std::int64_t batch,
         const GeometricSolveOptions& options)
      : geometry_(geometry),
        sites_(std::move(sites)),
        index_(std::move(index)),
        batch_(batch),
        groups_(geometry.groups()),
        options_(options) {
    // Cut: a site on the outermost row or column (|px| > half extent - 1).
    const auto limit = torch::tensor(
        {0.5 * (options.width_px - 2) * options.pitch_um, 0.5 * (options.height_px - 2) * options.pitch_um}, kDouble);
    on_edge_ = (sites_.abs() > limit).any(1);
  }

  // Each site's spot (image * G + the group of the aperture whose spot is
  // nearest at `angles`) and its squared distance from that aperture's spot.
  std::pair<torch::Tensor, torch::Tensor> associate(const torch::Tensor& angles) const {
    const auto predicted = geometry_.spotsUm(angles).index_select(0, index_);  // [N, K, 2]
    const auto distance2 = (sites_.unsqueeze(1) - predicted).pow(2).sum(2);    // [N, K]
    const auto [nearest2, aperture] = distance2.min(1);
    return {index_ * groups_ + geometry_.aperture_group.index_select(0, aperture), nearest2};
  }
  torch::Tensor inGate(const torch::Tensor& distance2) const { return distance2 < options_.gate_um * options_.gate_um; }
  SpotReads read(const torch::Tensor& w, const torch::Tensor& spot, const torch::Tensor& inside) const {
    return readSpots(sites_, w * inside.to(torch::kFloat64), on_edge_ & inside, spot, batch_ * groups_);
  }
  // Weight of each spot in the solve [B, G]: sum / spread, whole spots only
  // where the image has one.
  torch::Tensor solveWeights(const SpotReads& r) const {
    const auto spread = r.spread.clamp_min(options_.pitch_um * options_.pitch_um / 6.0);
    const auto all = torch::where(r.sum > 0, r.sum / spread, torch::zeros_like(r.sum)).view({batch_, groups_});
    const auto whole = all * (~r.cut).to(torch::kFloat64).view({batch_, groups_});
    return torch::where(whole.sum(1, true) > 0, whole, all);
  }
  torch::Tensor jacobian(const torch::Tensor& angles) const {  // d(spot um)/d(angle) [B, G, 2, 2]
    constexpr double kStep = 1e-6;
    std::vector<torch::Tensor> columns;
    for (int axis = 0; axis < 2; ++axis) {
      auto delta = torch::zeros({1, 2}, kDouble);
      delta[0][axis] = kStep;
      columns.push_back((geometry_.groupSpotsUm(angles + delta) - geometry_.groupSpotsUm(angles - delta)) /
                        (2.0 * kStep));
    }
    return torch::stack(columns, 3);
  }
  // Inverse of the normal matrix A = sum_k W_k J_k^T J_k [B, 2, 2] (zero
  // where the image reads no spot).
  torch::Tensor normalInverse(const torch::Tensor& jac, const torch::Tensor& w) const {
    const auto a = (w.view({batch_, groups_, 1, 1}) * jac.transpose(2, 3).matmul(jac)).sum(1);
    const auto a00 = a.select(1, 0).select(1, 0), a01 = a.select(1, 0).select(1, 1);
    const auto a10 = a.select(1, 1).select(1, 0), a11 = a.select(1, 1).select(1, 1);
    const auto det = a00 * a11 - a01 * a10;
    const auto inv_det = torch::where(det > 1e-300, 1.0 / det.clamp_min(1e-300), torch::zeros_like(det));
    return torch::stack({torch::stack({a11, -a01}, 1), torch::stack({-a10, a00}, 1)}, 1) * inv_det.view({-1, 1, 1});
  }
  // J^T W r per image [B, 2] for spots [B, G, 2] about predicted [B, G, 2].
  torch::Tensor gradient(const torch::Tensor& jac, const torch::Tensor& w, const torch::Tensor& spots,
                         const torch::Tensor& predicted) const {
    const auto r = (spots - predicted).unsqueeze(3);
    return (w.view({batch_, groups_, 1, 1}) * jac.transpose(2, 3).matmul(r)).sum(1).squeeze(2);
  }
  // Rounds of association and Gauss-Newton from `angles` (no autograd).
  torch::Tensor refine(torch::Tensor angles, const torch::Tensor& w) const {
    for (int round = 0; round < options_.association_rounds; ++round) {
      const auto [spot, distance2] = associate(angles);
      const SpotReads r = read(w, spot, inGate(distance2));
      const auto solve_w = solveWeights(r);
      const auto spots = r.centroid.view({batch_, groups_, 2});
      for (int it = 0; it < options_.gauss_newton_iterations; ++it) {
        const auto jac = jacobian(angles);
        const auto step = normalInverse(jac, solve_w)
                              .matmul(gradient(jac, solve_w, spots, geometry_.groupSpotsUm(angles)).unsqueeze(2))
                              .squeeze(2);
        // Angles stay inside the hemisphere whatever a wild step says.
        angles = (angles + step).clamp(-1.4, 1.4);
      }
    }
    return angles;
  }
  // How well spots at `angles` [B, 2] account for the light w [N] (no
  // autograd): the fraction of each image's light within half a gate of a
  // spot, less the fraction of the spots the detector should show (centre
  // a quarter gate inside its edges) that hold under 2 % of the light.
  torch::Tensor score(const torch::Tensor& angles, const torch::Tensor& w) const {
    const auto [spot, distance2] = associate(angles);
    const auto near = (distance2 < 0.25 * options_.gate_um * options_.gate_um).to(torch::kFloat64);
    const auto total = torch::zeros({batch_}, kDouble).index_add(0, index_, w).clamp_min(1e-30);
    const auto explained = torch::zeros({batch_}, kDouble).index_add(0, index_, w * near) / total;
    const auto light = torch::zeros({batch_ * groups_}, kDouble).index_add(0, spot, w * near).view({batch_, groups_});
    const auto limit = torch::tensor({0.5 * options_.width_px * options_.pitch_um - 0.25 * options_.gate_um,
                                      0.5 * options_.height_px * options_.pitch_um - 0.25 * options_.gate_um},
                                     kDouble);
    const auto expected = (geometry_.groupSpotsUm(angles).abs() < limit).all(2).to(torch::kFloat64);
    const auto dark = expected * (light < 0.02 * total.view({-1, 1})).to(torch::kFloat64);
    return explained - dark.sum(1) / expected.sum(1).clamp_min(1.0);
  }
  std::int64_t batch() const { return batch_; }
  std::int64_t groups() const { return groups_; }

 private:
  const SensorGeometryImpl& geometry_;
  torch::Tensor sites_, index_, on_edge_;
  std::int64_t batch_, groups_;
  GeometricSolveOptions options_;
};

// The best of the reference and, per group, the angles that put its spot on
// the image's heaviest site, each refined and then scored (Solver::score).
torch::Tensor searchReference(const SensorGeometryImpl& geometry, const torch::Tensor& sites, const torch::Tensor& w,
                              const torch::Tensor& index, std::int64_t batch, const torch::Tensor& reference,
                              const GeometricSolveOptions& options) {
  const std::int64_t groups = geometry.groups(), hypotheses = groups + 1;
  // The anchor: each image's heaviest site (the first of equals; an image
  // without sites gets the origin and keeps its reference).
  const std::int64_t n = sites.size(0);
  const auto heaviest = torch::zeros({batch}, kDouble).scatter_reduce(0, index, w, "amax", false);
  const auto row = torch::where(w == heaviest.index_select(0, index), torch::arange(n, torch::kLong),
                                torch::full({n}, n, torch::kLong));
  const auto first = torch::full({batch}, n, torch::kLong).scatter_reduce(0, index, row, "amin", true);
  const auto anchor = torch::cat({sites, torch::zeros({1, 2}, kDouble)}).index_select(0, first);
  const auto group = torch::arange(groups, torch::kLong).repeat({batch});
  const auto placed = invertGroups(geometry, group, anchor.repeat_interleave(groups, 0)).view({batch, groups, 2});
  const auto candidates = torch::cat({reference.unsqueeze(1), placed}, 1).view({-1, 2});  // [B * H, 2]
  // Every site once per hypothesis: image b's hypothesis h is row b * H + h.
  const auto hypothesis = torch::arange(hypotheses, torch::kLong);
  const Solver expanded(geometry, sites.repeat_interleave(hypotheses, 0),
                        (index.view({-1, 1}) * hypotheses + hypothesis.view({1, -1})).view({-1}), batch * hypotheses,
                        options);
  const auto w_expanded = w.repeat_interleave(hypotheses, 0);
  const auto refined = expanded.refine(candidates, w_expanded);
  const auto best = expanded.score(refined, w_expanded).view({batch, hypotheses}).argmax(1);  // first of equals
  return refined.view({batch, hypotheses, 2}).gather(1, best.view({-1, 1, 1}).expand({-1, 1, 2})).squeeze(1);
}

}  // namespace

GeometricSolution solveGeometry(const SensorGeometryImpl& geometry, const torch::Tensor& site_um,
                                const torch::Tensor& weight, const torch::Tensor& index, std::int64_t batch,
                                const torch::Tensor& reference_rad, const GeometricSolveOptions& options) {
  const auto sites = site_um.detach().to(torch::kFloat64);
  const Solver solver(geometry, sites, index, batch, options);
  const std::int64_t groups = geometry.groups();
  torch::Tensor angles = reference_rad.detach().to(torch::kFloat64);
  {
    torch::NoGradGuard no_grad;
    const auto w = weight.detach().to(torch::kFloat64);
    if (options.search_reference && sites.size(0) > 0)
      angles = searchReference(geometry, sites, w, index, batch, angles, options);
    angles = solver.refine(angles, w);
  }
  // The last association and step in the graph.
  const auto [spot, distance2] = solver.associate(angles);
  const SpotReads r = solver.read(weight.to(torch::kFloat64), spot, solver.inGate(distance2));
  const auto solve_w = solver.solveWeights(r);
  const auto spots = r.centroid.view({batch, groups, 2});
  const auto jac = solver.jacobian(angles).detach();
  const auto inverse = solver.normalInverse(jac, solve_w.detach()).detach();
  const auto predicted = geometry.groupSpotsUm(angles);
  GeometricSolution out;
  out.angles_rad = angles + inverse.matmul(solver.gradient(jac, solve_w, spots, predicted).unsqueeze(2)).squeeze(2);
  torch::NoGradGuard no_grad;
  out.log_variance = torch::log(
      torch::stack({inverse.select(1, 0).select(1, 0), inverse.select(1, 1).select(1, 1)}, 1).clamp_min(1e-300));
  const auto read = (solve_w.detach() > 0).to(torch::kFloat64);
  out.spots_read = read.sum(1);
  const auto squared = (spots.detach() - predicted.detach()).pow(2).sum(2) * read;
  out.residual_um = (squared.sum(1) / out.spots_read.clamp_min(1.0)).sqrt();
  return out;
}

}  // namespace dss
