#include "digital_sun_sensor/model/geometric_head.h"

#include <torch/torch.h>

#include <algorithm>
#include <stdexcept>
#include <string>

#include "digital_sun_sensor/sparse/ops.h"
#include "geometric_solve.h"

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

// Per image and group: the summed weight [B*G], the weighted centroid
// [B*G, 2] and the weighted spread s^2 [B*G] of the sites assigned to it
// (spot = index * G + group).
struct SpotReads {
  torch::Tensor sum, centroid, spread;
};

SpotReads readSpots(const torch::Tensor& site_um, const torch::Tensor& weight, const torch::Tensor& spot,
                    std::int64_t spots) {
  SpotReads r;
  auto per_spot = [&](const torch::Tensor& values) { return sparse::indexSum(values, spot, spots); };
  const auto w = weight.view({-1, 1});
  r.sum = per_spot(w).view({-1});
  const auto safe = r.sum.clamp_min(1e-30).view({-1, 1});
  r.centroid = per_spot(w * site_um) / safe;
  r.spread = (per_spot(w * site_um * site_um) / safe - r.centroid * r.centroid).sum(1);
  return r;
}

}  // namespace

SensorGeometryImpl::SensorGeometryImpl(int apertures, int groups, double air_above_exit_um)
    : group_count_(groups), air_above_exit_um_(air_above_exit_um) {
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
  setDesignHeight(design);
}

torch::Tensor SensorGeometryImpl::spotsUm(const torch::Tensor& angles_rad) const {
  const auto apertures = apertures_um.size(0);
  const auto mask_frame = torch::cat({apertures_um, torch::zeros({apertures, 1}, kDouble)}, 1);  // [K, 3]
  const auto centres = mask_frame.matmul(maskRotation(rotation_rad, tilt_rad).t()) +
                       torch::cat({offset_um, height_um}).unsqueeze(0);  // [K, 3], exit face
  const auto z = centres.select(1, 2);
  // A mask lower than the glass (a negative height error) rests on a
  // thinner slab: the glass never extends above the aperture's exit face,
  // air_above_exit_um_ below the height (the mid-plane).
  const auto glass = torch::minimum(glass_thickness_um.expand_as(z), (z - air_above_exit_um_).clamp_min(0.0));
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
  auto spots = spotsUm(angles_rad);
  if (group_count_ != apertures()) {
    const auto flux = aperture_flux.view({1, -1, 1});
    const auto sum = torch::zeros({group_count_}, kDouble).index_add(0, aperture_group, aperture_flux);
    spots = torch::zeros({spots.size(0), group_count_, 2}, kDouble).index_add(1, aperture_group, spots * flux) /
            sum.view({1, -1, 1});
  }
  if (!spot_bias_here_.active()) return spots;
  const auto angles = angles_rad.detach().to(torch::kFloat64).contiguous();
  const auto a = angles.accessor<double, 2>();
  auto bias = torch::zeros({angles.size(0), group_count_, 2}, kDouble);
  auto b = bias.accessor<double, 3>();
  std::vector<Eigen::Vector2d> per_group(static_cast<std::size_t>(group_count_));
  for (std::int64_t i = 0; i < angles.size(0); ++i) {
    std::fill(per_group.begin(), per_group.end(), Eigen::Vector2d::Zero());
    spot_bias_here_.addTo(Eigen::Vector2d(a[i][0], a[i][1]), per_group);
    for (std::int64_t g = 0; g < group_count_; ++g) {
      b[i][g][0] = per_group[static_cast<std::size_t>(g)].x();
      b[i][g][1] = per_group[static_cast<std::size_t>(g)].y();
    }
  }
  return spots + bias;
}

MaskGeometry SensorGeometryImpl::maskGeometry() const {
  MaskGeometry m;
  m.pitch_um = 1.0;
  m.height_um = height_um.item<double>();
  m.offset_x_um = offset_um[0].item<double>();
  m.offset_y_um = offset_um[1].item<double>();
  m.rotation_rad = rotation_rad.item<double>();
  m.tilt_x_rad = tilt_rad[0].item<double>();
  m.tilt_y_rad = tilt_rad[1].item<double>();
  m.glass_thickness_um = glass_thickness_um.item<double>();
  m.glass_index = glass_index.item<double>();
  m.air_above_exit_um = air_above_exit_um_;
  const auto a = apertures_um.contiguous();
  const auto xy = a.accessor<double, 2>();
  for (std::int64_t k = 0; k < a.size(0); ++k) m.apertures_um.emplace_back(xy[k][0], xy[k][1]);
  return m;
}

void SensorGeometryImpl::setMaskGeometry(const MaskGeometry& m) {
  if (m.numApertures() != apertures())
    throw std::invalid_argument("sensor geometry: " + std::to_string(m.numApertures()) + " apertures for a model of " +
                                std::to_string(apertures()));
  if (!(m.height_um > 0.0) || !std::isfinite(m.height_um))
    throw std::invalid_argument("sensor geometry: the mask height must be positive");
  torch::NoGradGuard no_grad;
  height_um.fill_(m.height_um);
  offset_um[0] = m.offset_x_um;
  offset_um[1] = m.offset_y_um;
  rotation_rad.fill_(m.rotation_rad);
  tilt_rad[0] = m.tilt_x_rad;
  tilt_rad[1] = m.tilt_y_rad;
  for (int k = 0; k < m.numApertures(); ++k) {
    apertures_um[k][0] = m.apertures_um[static_cast<std::size_t>(k)].x();
    apertures_um[k][1] = m.apertures_um[static_cast<std::size_t>(k)].y();
  }
  spot_bias_here_ = spotBiasAt(m.height_um);
}

void SensorGeometryImpl::setDesignHeight(const GeometryDesign& design) {
  design_height_um_ = design.height_um;
  spot_bias_here_ = spotBiasAt(height_um.item<double>());
}

void SensorGeometryImpl::setPositionVariance(const std::vector<double>& aperture_variance_um2, double spot_noise_um2) {
  if (aperture_variance_um2.empty()) {
    group_variance_.clear();
    return;
  }
  if (static_cast<int>(aperture_variance_um2.size()) != apertures())
    throw std::invalid_argument("sensor geometry: " + std::to_string(aperture_variance_um2.size()) +
                                " aperture position variances for a model of " + std::to_string(apertures()));
  if (!(spot_noise_um2 > 0.0) || !std::isfinite(spot_noise_um2))
    throw std::invalid_argument("sensor geometry: the spot noise must be positive");
  // A group's spot is its apertures' flux-weighted mean.
  std::vector<double> variance(static_cast<std::size_t>(groups()), 0.0), flux(variance.size(), 0.0);
  const auto group = aperture_group.contiguous();
  const auto aperture_fluxes = aperture_flux.contiguous();
  for (int k = 0; k < apertures(); ++k) {
    const double v = aperture_variance_um2[static_cast<std::size_t>(k)];
    if (!(v >= 0.0) || !std::isfinite(v))
      throw std::invalid_argument("sensor geometry: aperture " + std::to_string(k) +
                                  "'s position variance is not >= 0");
    const auto g = static_cast<std::size_t>(group[k].item<std::int64_t>());
    const double f = aperture_fluxes[k].item<double>();
    variance[g] += f * f * v;
    flux[g] += f;
  }
  for (std::size_t g = 0; g < variance.size(); ++g)
    variance[g] = flux[g] > 0.0 ? variance[g] / (flux[g] * flux[g]) / spot_noise_um2 : 0.0;
  group_variance_ = std::move(variance);
}

void SensorGeometryImpl::setSpotBias(const SpotBias& bias) {
  bias.validate(groups());
  spot_bias_ = bias;
  spot_bias_here_ = spotBiasAt(height_um.item<double>());
}

SpotBias SensorGeometryImpl::spotBiasAt(double mask_height_um) const {
  return spot_bias_.at(design_height_um_ ? mask_height_um - *design_height_um_ : 0.0);
}

geometric::Design geometric::designOf(const SensorGeometryImpl& geometry) {
  geometric::Design d;
  d.mask = geometry.maskGeometry();
  const auto group = geometry.aperture_group.contiguous();
  const auto flux = geometry.aperture_flux.contiguous();
  for (std::int64_t k = 0; k < group.size(0); ++k) {
    d.group.push_back(static_cast<int>(group[k].item<std::int64_t>()));
    d.flux.push_back(flux[k].item<double>());
  }
  d.groups = geometry.groups();
  d.spot_bias = geometry.spotBias();
  return d;
}

GeometricSolution solveGeometry(const SensorGeometryImpl& geometry, const torch::Tensor& site_um,
                                const torch::Tensor& weight, const torch::Tensor& index, std::int64_t batch,
                                const torch::Tensor& reference_rad, const GeometricSolveOptions& options) {
  const std::int64_t groups = geometry.groups();
  const auto sites = site_um.detach().to(torch::kFloat64).contiguous();
  const auto plain_weight = weight.detach().to(torch::kFloat64).reshape({-1}).contiguous();
  const auto image = index.to(torch::kLong).contiguous();
  const auto reference = reference_rad.detach().to(torch::kFloat64).contiguous();
  const std::int64_t n = sites.size(0);

  // The search and the iterations, image by image, without autograd.
  const geometric::Design design = geometric::designOf(geometry);
  geometric::Options plain;
  plain.gate_um = options.gate_um;
  plain.pitch_um = options.pitch_um;
  plain.width_px = options.width_px;
  plain.height_px = options.height_px;
  plain.rounds = options.association_rounds;
  plain.iterations = options.gauss_newton_iterations;
  plain.search = options.search_reference;
  plain.symmetric_spots = options.symmetric_spots;
  plain.group_variance = geometry.groupPositionVariance();
  const auto xy = sites.accessor<double, 2>();
  const auto w = plain_weight.accessor<double, 1>();
  const auto b_of = image.accessor<std::int64_t, 1>();
  const auto ref = reference.accessor<double, 2>();
  std::vector<std::vector<geometric::Site>> per_image(static_cast<std::size_t>(batch));
  std::vector<std::vector<std::int64_t>> rows(static_cast<std::size_t>(batch));
  for (std::int64_t i = 0; i < n; ++i) {
    const auto b = static_cast<std::size_t>(b_of[i]);
    per_image[b].push_back({Eigen::Vector2d(xy[i][0], xy[i][1]), w[i]});
    rows[b].push_back(i);
  }
  auto angles = torch::zeros({batch, 2}, kDouble);
  auto spot = torch::zeros({n}, torch::kLong);
  auto inside = torch::zeros({n}, kDouble);
  auto read_um = sites.clone();
  auto read = torch::zeros({batch, groups}, torch::kBool);
  auto jac = torch::zeros({batch, groups, 2, 2}, kDouble);
  auto inverse = torch::zeros({batch, 2, 2}, kDouble);
  auto lone = torch::zeros({batch}, torch::kBool);
  {
    auto a = angles.accessor<double, 2>();
    auto s = spot.accessor<std::int64_t, 1>();
    auto in = inside.accessor<double, 1>();
    auto at = read_um.accessor<double, 2>();
    auto r = read.accessor<bool, 2>();
    auto j = jac.accessor<double, 4>();
    auto inv = inverse.accessor<double, 3>();
    auto ambiguous = lone.accessor<bool, 1>();
    for (std::int64_t b = 0; b < batch; ++b) {
      const auto& image_sites = per_image[static_cast<std::size_t>(b)];
      const auto solution = geometric::solveImage(design, image_sites, Eigen::Vector2d(ref[b][0], ref[b][1]), plain);
      a[b][0] = solution.angles_rad.x();
      a[b][1] = solution.angles_rad.y();
      ambiguous[b] = solution.lone_spot_ambiguous;
      for (std::size_t k = 0; k < image_sites.size(); ++k) {
        const std::int64_t row = rows[static_cast<std::size_t>(b)][k];
        const int g = solution.group[k];
        s[row] = b * groups + std::max(g, 0);
        in[row] = g >= 0 ? 1.0 : 0.0;
        at[row][0] = solution.read_um[k].x();
        at[row][1] = solution.read_um[k].y();
      }
      for (std::int64_t g = 0; g < groups; ++g) {
        r[b][g] = solution.weight[static_cast<std::size_t>(g)] > 0.0;
        for (int u = 0; u < 2; ++u)
          for (int v = 0; v < 2; ++v) j[b][g][u][v] = solution.jacobian[static_cast<std::size_t>(g)](u, v);
      }
      for (int u = 0; u < 2; ++u)
        for (int v = 0; v < 2; ++v) inv[b][u][v] = solution.normal_inverse(u, v);
    }
  }
  // The last step in the graph: the spots and their weights from the site
  // weights, where the plain solve read the sites (a cut spot's moved to its
  // fitted centre), the geometry's spots from its tensors; Jacobian and
  // normal matrix held at the solution.
  const SpotReads r = readSpots(read_um, weight.reshape({-1}).to(torch::kFloat64) * inside, spot, batch * groups);
  const auto spread = r.spread.clamp_min(options.pitch_um * options.pitch_um / 6.0).view({batch, groups});
  auto solve_w = torch::where(read, r.sum.view({batch, groups}) / spread, torch::zeros_like(spread));
  if (!plain.group_variance.empty())  // as geometric::solveWeights
    solve_w = solve_w / (1.0 + solve_w * torch::tensor(plain.group_variance, kDouble).view({1, groups}));
  const auto spots = r.centroid.view({batch, groups, 2});
  const auto predicted = geometry.groupSpotsUm(angles);
  const auto residual = (spots - predicted).unsqueeze(3);  // [B, G, 2, 1]
  const auto gradient = (solve_w.view({batch, groups, 1, 1}) * jac.transpose(2, 3).matmul(residual)).sum(1);
  GeometricSolution out;
  out.angles_rad = angles + inverse.matmul(gradient).squeeze(2);
  out.lone_spot_ambiguous = lone;
  torch::NoGradGuard no_grad;
  out.log_variance = torch::log(
      torch::stack({inverse.select(1, 0).select(1, 0), inverse.select(1, 1).select(1, 1)}, 1).clamp_min(1e-300));
  const auto read_spots = read.to(torch::kFloat64);
  out.spots_read = read_spots.sum(1);
  // The residual at the final angles: where the plain solve stopped short
  // (a few micrometres on ~1 % of an untrained head's images), the residual
  // at its angles measured that shortfall, not the spots' fit.
  const auto final_predicted = geometry.groupSpotsUm(out.angles_rad.detach());
  const auto squared = (spots.detach() - final_predicted).pow(2).sum(2) * read_spots;
  out.residual_um = (squared.sum(1) / out.spots_read.clamp_min(1.0)).sqrt();
  const auto dof = 2.0 * out.spots_read - 2.0;
  out.residual_per_dof =
      torch::where(dof > 0, (squared * solve_w.detach()).sum(1) / dof.clamp_min(1.0), torch::zeros_like(dof));
  return out;
}

}  // namespace dss
