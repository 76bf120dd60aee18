#include "digital_sun_sensor/model/sscnn.h"

#include <torch/nn/functional/activation.h>
#include <torch/nn/functional/conv.h>
#include <torch/nn/functional/pooling.h>

#include <algorithm>
#include <cmath>

#include "digital_sun_sensor/sparse/ops.h"
#include "lattice_code.h"

namespace dss {

using sparse::RulebookCache;
using sparse::SparseTensor;
namespace F = torch::nn::functional;

// ---- SparseConv

SparseConvImpl::SparseConvImpl(int in_channels, int out_channels, int kernel_size_, int stride_, bool bias_)
    : kernel_size(kernel_size_), stride(stride_) {
  // He initialisation for ReLU networks: std = sqrt(2 / fan_in).
  const double fan_in = static_cast<double>(kernel_size * kernel_size * in_channels);
  weight = register_parameter(
      "weight", torch::randn({kernel_size * kernel_size, in_channels, out_channels}) * std::sqrt(2.0 / fan_in));
  if (bias_) bias = register_parameter("bias", torch::zeros({out_channels}));
}

SparseTensor SparseConvImpl::forward(const SparseTensor& x) {
  auto rb = stride == 1 ? x.rulebook(RulebookCache::Kind::kSubmanifold, kernel_size)
                        : x.rulebook(RulebookCache::Kind::kStrided, kernel_size, stride, kernel_size / 2);
  auto f = sparse::sparseConv(x.features, weight, *rb);
  if (bias.defined()) f = f + bias;
  return {f, rb->output, x.rulebooks};
}

SparseTensor SparseConvImpl::forwardShortcut(const SparseTensor& x, int main_kernel_size) {
  auto rb = x.rulebook(RulebookCache::Kind::kShortcut, main_kernel_size, stride);
  auto f = sparse::sparseConv(x.features, weight, *rb);
  if (bias.defined()) f = f + bias;
  return {f, rb->output, x.rulebooks};
}

torch::Tensor SparseConvImpl::forwardDense(const torch::Tensor& x) {
  const auto c_in = weight.size(1), c_out = weight.size(2);
  auto w = weight.permute({2, 1, 0}).reshape({c_out, c_in, kernel_size, kernel_size});
  return F::conv2d(x, w, F::Conv2dFuncOptions().bias(bias).stride(stride).padding(kernel_size / 2));
}

// ---- ResidualBlock

ResidualBlockImpl::ResidualBlockImpl(int in_channels, int out_channels, int stride, bool batch_norm) : stride_(stride) {
  conv1_ =
      register_module("conv1", std::make_shared<SparseConvImpl>(in_channels, out_channels, 3, stride, !batch_norm));
  conv2_ = register_module("conv2", std::make_shared<SparseConvImpl>(out_channels, out_channels, 3, 1, !batch_norm));
  if (batch_norm) {
    bn1_ = register_module("bn1", torch::nn::BatchNorm1d(out_channels));
    bn2_ = register_module("bn2", torch::nn::BatchNorm1d(out_channels));
    torch::NoGradGuard no_grad;
    bn2_->weight.zero_();  // each block starts as the identity (trainable deep nets)
  } else {
    torch::NoGradGuard no_grad;
    conv2_->weight.zero_();  // Fixup-style: identity blocks at start, no normalisation needed
  }
  if (stride != 1 || in_channels != out_channels)
    shortcut_ =
        register_module("shortcut", std::make_shared<SparseConvImpl>(in_channels, out_channels, 1, stride, false));
}

torch::Tensor ResidualBlockImpl::norm(torch::nn::BatchNorm1d& bn, const torch::Tensor& f) {
  return bn.is_empty() ? f : bn->forward(f);
}

torch::Tensor ResidualBlockImpl::normDense(torch::nn::BatchNorm1d& bn, const torch::Tensor& f) {
  if (bn.is_empty()) return f;
  // BatchNorm1d over channels of a [B, C, H, W] map: fold spatial dims into the batch.
  const auto s = f.sizes();
  return bn->forward(f.permute({0, 2, 3, 1}).reshape({-1, s[1]}))
      .reshape({s[0], s[2], s[3], s[1]})
      .permute({0, 3, 1, 2});
}

SparseTensor ResidualBlockImpl::forward(const SparseTensor& x) {
  SparseTensor h = conv1_->forward(x);
  h = h.with(torch::relu(norm(bn1_, h.features)));
  h = conv2_->forward(h);
  torch::Tensor identity = x.features;
  if (shortcut_) identity = stride_ == 1 ? shortcut_->forward(x).features : shortcut_->forwardShortcut(x, 3).features;
  return h.with(torch::relu(norm(bn2_, h.features) + identity));
}

torch::Tensor ResidualBlockImpl::forwardDense(const torch::Tensor& x) {
  auto h = torch::relu(normDense(bn1_, conv1_->forwardDense(x)));
  h = normDense(bn2_, conv2_->forwardDense(h));
  return torch::relu(h + (shortcut_ ? shortcut_->forwardDense(x) : x));
}

// ---- Network

SscnnNetImpl::SscnnNetImpl(const ArchSpec& arch) : arch_(arch) {
  arch_.validate();
  stem_ = register_module(
      "stem", std::make_shared<SparseConvImpl>(arch.input_channels, arch.stem_width, arch.stem_kernel, 2, true));
  int channels = arch.stem_width;
  for (std::size_t stage = 0; stage < arch.blocks.size(); ++stage) {
    for (int b = 0; b < arch.blocks[stage]; ++b) {
      const int stride = (b == 0 && stage > 0) ? 2 : 1;
      blocks_.push_back(
          register_module("stage" + std::to_string(stage + 1) + "_block" + std::to_string(b + 1),
                          std::make_shared<ResidualBlockImpl>(channels, arch.widths[stage], stride, arch.batch_norm)));
      channels = arch.widths[stage];
    }
  }
  int features = 2 * channels;  // average + max pooled
  if (arch.centroid_pool) {
    centroid_conv1_ =
        register_module("centroid_conv1", std::make_shared<SparseConvImpl>(1, arch.centroid_width, 3, 1, true));
    centroid_conv2_ =
        register_module("centroid_conv2", std::make_shared<SparseConvImpl>(arch.centroid_width, 1, 1, 1, true));
    const int monomials = (arch.centroid_degree + 1) * (arch.centroid_degree + 2) / 2 - 1;
    centroid_skip_ = register_module("centroid_skip", torch::nn::Linear(monomials, 2));
    centroid_prior_ = register_buffer("centroid_prior", torch::zeros({2}));
    features += 2;
  }
  head_norm_ = register_module("head_norm", torch::nn::LayerNorm(torch::nn::LayerNormOptions({2 * channels})));
  for (std::size_t i = 0; i < arch.head_hidden.size(); ++i) {
    mlp_.push_back(register_module("mlp" + std::to_string(i + 1), torch::nn::Linear(features, arch.head_hidden[i])));
    features = arch.head_hidden[i];
  }
  output_ = register_module("output", torch::nn::Linear(features, 2));
  // The variance reads the angle MLP's features but sends no gradient into
  // them: its NLL, which grows as the variance shrinks, would otherwise steer
  // the features the angles need.
  variance_ = register_module("variance", torch::nn::Linear(features, 2));
  // The classes get their own branch: in a shared MLP the angle NLL's gradients,
  // which grow as the variance shrinks, drown the cross-entropy's.
  const bool class_resolved = arch.apertureClassLattice();
  if (class_resolved)  // per class: its aperture's spot offset from the lattice centre (initLatticeApertures)
    lattice_class_offsets_ = register_buffer("lattice_class_offsets", torch::zeros({arch.num_classes, 2}));
  if (class_resolved && arch.lattice_resolve == LatticeResolve::kCode)
    lattice_log_area_ = register_buffer("lattice_log_area", torch::zeros({arch.lattice_rows, arch.lattice_columns}));
  if (arch.geometric_prior_size > 0) {
    geometric_prior_ =
        register_buffer("geometric_prior", torch::zeros({1, 2, arch.geometric_prior_size, arch.geometric_prior_size}));
    geometric_prior_extent_ = register_buffer("geometric_prior_extent", torch::ones({2}));
  }
  const int head_in = 2 * channels + (arch.centroid_pool ? 2 : 0) + (class_resolved ? 4 : 0);
  const int class_hidden = arch.head_hidden.back();
  class_hidden_ = register_module("class_hidden", torch::nn::Linear(head_in, class_hidden));
  class_output_ = register_module("class_output", torch::nn::Linear(class_hidden, arch.num_classes));
  torch::NoGradGuard no_grad;
  output_->weight.zero_();  // start with angle corrections of zero...
  output_->bias.zero_();
  variance_->weight.mul_(0.1);  // ...and unit variance
  variance_->bias.zero_();
}

void SscnnNetImpl::initCentroidMap(double slope_x, double slope_y) {
  if (!arch_.centroid_pool) return;
  torch::NoGradGuard no_grad;
  centroid_conv2_->weight.zero_();  // softplus(0): equal weights
  centroid_conv2_->bias.zero_();
  centroid_skip_->weight.zero_();
  centroid_skip_->bias.zero_();
  centroid_prior_[0] = slope_x;
  centroid_prior_[1] = slope_y;
}

void SscnnNetImpl::initLatticeApertures(const std::vector<std::array<double, 2>>& offsets,
                                        const std::vector<double>& areas_um2) {
  if (!lattice_class_offsets_.defined()) return;
  if (static_cast<std::int64_t>(offsets.size()) != lattice_class_offsets_.size(0) || areas_um2.size() != offsets.size())
    throw std::invalid_argument("initLatticeApertures: " + std::to_string(offsets.size()) + " offsets and " +
                                std::to_string(areas_um2.size()) + " areas for " +
                                std::to_string(lattice_class_offsets_.size(0)) + " classes");
  torch::NoGradGuard no_grad;
  for (std::size_t c = 0; c < offsets.size(); ++c)
    for (int axis = 0; axis < 2; ++axis)
      lattice_class_offsets_[static_cast<std::int64_t>(c)][axis] = offsets[c][static_cast<std::size_t>(axis)];
  if (!lattice_log_area_.defined()) return;
  std::vector<bool> filled(static_cast<std::size_t>(arch_.lattice_rows * arch_.lattice_columns), false);
  for (std::size_t c = 0; c < offsets.size(); ++c) {
    const long col = std::lround(offsets[c][0] / arch_.lattice_pitch_x + 0.5 * (arch_.lattice_columns - 1));
    const long row = std::lround(offsets[c][1] / arch_.lattice_pitch_y + 0.5 * (arch_.lattice_rows - 1));
    if (col < 0 || row < 0 || col >= arch_.lattice_columns || row >= arch_.lattice_rows || !(areas_um2[c] > 0.0))
      throw std::invalid_argument("initLatticeApertures: aperture " + std::to_string(c) +
                                  " is off the lattice or has no area");
    filled[static_cast<std::size_t>(row * arch_.lattice_columns + col)] = true;
    lattice_log_area_[row][col] = std::log(areas_um2[c]);
  }
  if (std::find(filled.begin(), filled.end(), false) != filled.end())
    throw std::invalid_argument("initLatticeApertures: the apertures do not fill the lattice");
}

void SscnnNetImpl::initGeometricPrior(const torch::Tensor& table, double extent_x, double extent_y) {
  if (!geometric_prior_.defined()) return;
  if (table.sizes() != geometric_prior_.sizes().slice(1))
    throw std::invalid_argument("initGeometricPrior: the table must be [2, size, size] of the architecture");
  if (!(extent_x > 0.0 && extent_y > 0.0)) throw std::invalid_argument("initGeometricPrior: extents must be positive");
  torch::NoGradGuard no_grad;
  geometric_prior_.copy_(table.unsqueeze(0));
  geometric_prior_extent_[0] = extent_x;
  geometric_prior_extent_[1] = extent_y;
}

torch::Tensor SscnnNetImpl::priorAngles(const torch::Tensor& position) const {
  if (!geometric_prior_.defined()) return position * centroid_prior_;
  // Catmull-Rom over the 4 x 4 nearest nodes: exact for quadratics, unlike
  // torch's bicubic grid_sample (a = -0.75), which misses even a linear map by
  // up to 15 % of a node spacing.
  const std::int64_t size = geometric_prior_.size(2);
  const torch::Tensor u = (position / geometric_prior_extent_ + 1.0) * (0.5 * static_cast<double>(size - 1));  // [B, 2]
  const torch::Tensor base = u.detach().floor().clamp(1, static_cast<double>(size - 3));
  const torch::Tensor t = u - base;            // within [0, 1) inside the table, extrapolated beyond it
  auto weights = [](const torch::Tensor& x) {  // [B] -> [B, 4], nodes -1, 0, 1, 2
    const auto x2 = x * x, x3 = x2 * x;
    return torch::stack(
        {0.5 * (-x3 + 2 * x2 - x), 0.5 * (3 * x3 - 5 * x2 + 2), 0.5 * (-3 * x3 + 4 * x2 + x), 0.5 * (x3 - x2)}, 1);
  };
  const torch::Tensor wx = weights(t.select(1, 0)), wy = weights(t.select(1, 1));
  const torch::Tensor offsets = torch::arange(-1, 3, base.options().dtype(torch::kLong));
  const torch::Tensor cols = base.select(1, 0).to(torch::kLong).unsqueeze(1) + offsets;  // [B, 4]
  const torch::Tensor rows = base.select(1, 1).to(torch::kLong).unsqueeze(1) + offsets;
  const torch::Tensor flat = (rows.unsqueeze(2) * size + cols.unsqueeze(1)).view({-1});  // [B * 16]
  const torch::Tensor w = (wy.unsqueeze(2) * wx.unsqueeze(1)).view({-1, 16});            // [B, 16]
  const torch::Tensor table = geometric_prior_.view({2, -1});
  const torch::Tensor nodes = table.index_select(1, flat).view({2, -1, 16});  // [2, B, 16]
  return (nodes * w.unsqueeze(0)).sum(2).t();
}

std::int64_t SscnnNetImpl::parameterCount() const {
  std::int64_t n = 0;
  for (const auto& p : parameters()) n += p.numel();
  return n;
}

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
  result.log_variance = variance_->forward(h.detach());
  return result;
}

torch::Tensor SscnnNetImpl::centroidWeights(const torch::Tensor& logits, const torch::Tensor& value) const {
  if (arch_.centroid_weighting == CentroidWeighting::kIntensity) return value;
  const torch::Tensor learned = torch::softplus(logits);  // log(2) where the branch outputs 0 (its start)
  if (arch_.centroid_weighting == CentroidWeighting::kLearned) return learned;
  return value * learned * (1.0 / std::log(2.0));
}

SscnnNetImpl::SpotReading SscnnNetImpl::readSpots(const torch::Tensor& w, const torch::Tensor& xy,
                                                  const torch::Tensor& lit, const torch::Tensor& index,
                                                  std::int64_t batch) const {
  auto weighted_sum = [&](const torch::Tensor& values) {
    return torch::zeros({batch, values.size(1)}, values.options()).index_add(0, index, values);
  };
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
  auto per_spot = [&](const torch::Tensor& values) {
    return torch::zeros({spots, values.size(1)}, values.options()).index_add(0, spot, values);
  };
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

torch::Tensor SscnnNetImpl::latticeSteps(int axis, const torch::TensorOptions& options) const {
  const double pitch = arch_.latticePitch(axis);
  const int count = arch_.latticeCount(axis);
  // With an even count the spots sit half a pitch off the lattice centre.
  const double half_pitch = count % 2 == 0 ? 0.5 : 0.0;
  const int reach = static_cast<int>(std::ceil(std::max(1.5, 0.5 * count * pitch) / pitch)) + 1;
  return (torch::arange(-reach, reach + 1, options) + half_pitch) * pitch;
}

torch::Tensor SscnnNetImpl::resolveLattice(const SpotReading& spots, const torch::Tensor& class_logits,
                                           const torch::Tensor& known_classes) const {
  // The aperture code, in training too: the true class (the aperture whose
  // spot is nearest the detector centre) implies the shift only to within
  // half a pitch, which near the edge of the field, where the nearest spot
  // may lie further out, picks the wrong pitch.
  if (spots.code_steps.defined()) return spots.phase + spots.code_steps;
  torch::Tensor class_estimate;  // lattice shift the classes imply, [B, 2]
  if (known_classes.defined() && class_logits.defined()) {
    class_estimate = -lattice_class_offsets_.index_select(0, known_classes.to(torch::kLong));
  } else if (class_logits.defined()) {
    torch::NoGradGuard no_grad;
    // Expected over the class probabilities: between two neighbouring classes
    // the estimate stays within half a pitch of the truth.
    class_estimate = -torch::softmax(class_logits.detach(), 1).matmul(lattice_class_offsets_);
  }
  std::vector<torch::Tensor> shift(2);
  for (int axis = 0; axis < 2; ++axis) {
    const double pitch = arch_.latticePitch(axis);
    const int count = arch_.latticeCount(axis);
    const torch::Tensor phase = spots.phase.slice(1, axis, axis + 1);
    const torch::Tensor steps = latticeSteps(axis, phase.options());  // [K]
    torch::Tensor chosen_step;
    {
      torch::NoGradGuard no_grad;  // a discrete choice: gradients flow through the phase only
      const torch::Tensor candidates = phase.detach() + steps.unsqueeze(0);  // [B, K]
      torch::Tensor mismatch;
      if (class_estimate.defined()) {
        mismatch = (candidates - class_estimate.slice(1, axis, axis + 1)).abs();
      } else {
        // Each candidate predicts the centroid of the spots it leaves on the
        // detector (fading out over a spot radius at the edge); among those
        // the spots' presence does not contradict, the one nearest the
        // measured centroid wins. (The centroid alone, weighted by brightness,
        // goes wrong where a ghost brightens some spots and, through the
        // exposure, dims the others.)
        const torch::Tensor offsets = (torch::arange(count, phase.options()) - 0.5 * (count - 1)) * pitch;  // [n]
        const torch::Tensor lattice = candidates.unsqueeze(2) + offsets.view({1, 1, -1});                   // [B, K, n]
        const torch::Tensor visible = ((1.0 - lattice.abs()) / arch_.lattice_spot_radius + 0.5).clamp(0.0, 1.0);
        const torch::Tensor visible_total = visible.sum(2);
        const torch::Tensor predicted = (visible * lattice).sum(2) / visible_total.clamp_min(1e-6);
        mismatch = (predicted - spots.centroid.slice(1, axis, axis + 1).detach()).abs() +
                   (visible_total < 1e-3).to(predicted.scalar_type()) * 1e6;
        if (spots.contradictions[axis].defined()) mismatch = mismatch + spots.contradictions[axis] * 1e3;
      }
      chosen_step = steps.index_select(0, mismatch.argmin(1)).unsqueeze(1);
    }
    shift[axis] = phase + chosen_step;
  }
  return torch::cat(shift, 1);
}

SscnnOutput SscnnNetImpl::forward(const SparseTensor& input, const torch::Tensor& known_classes) {
  SparseTensor x = stem_->forward(input);
  x = x.with(torch::relu(x.features));
  if (arch_.stem_max_pool) {
    auto rb = x.rulebook(RulebookCache::Kind::kStrided, 3, 2, 1);
    x = {sparse::sparseMaxPool(x.features, *rb), rb->output, x.rulebooks};
  }
  for (auto& block : blocks_) x = block->forward(x);
  const torch::Tensor pooled =
      torch::cat({sparse::globalAvgPool(x.features, *x.sites), sparse::globalMaxPool(x.features, *x.sites)}, 1);
  SpotReading spots;
  if (arch_.centroid_pool) {
    // Learned weights w >= 0 per input site from the local pixel values only
    // (translation-equivariant: no position-dependent bias); centroid =
    // sum(w xy) / sum(w) per image.
    const torch::Tensor value = input.features.slice(1, 0, 1).contiguous();
    torch::Tensor logits;  // of the learned weights (none with intensity weights)
    if (arch_.centroid_weighting != CentroidWeighting::kIntensity) {
      SparseTensor c = centroid_conv1_->forward(input.with(value));
      logits = centroid_conv2_->forward(c.with(torch::relu(c.features))).features;
    }
    // Every site of the sparse input is lit.
    spots = readSpots(centroidWeights(logits, value), input.features.slice(1, 1, 3),
                      torch::ones({input.features.size(0)}, input.features.options()), sparse::batchIndex(*input.sites),
                      input.sites->batchSize());
  }
  return head(pooled, spots, known_classes);
}

SscnnOutput SscnnNetImpl::forwardDense(const torch::Tensor& input) {
  auto x = torch::relu(stem_->forwardDense(input));
  if (arch_.stem_max_pool) x = F::max_pool2d(x, F::MaxPool2dFuncOptions(3).stride(2).padding(1));
  for (auto& block : blocks_) x = block->forwardDense(x);
  const torch::Tensor pooled = torch::cat({x.mean({2, 3}), x.amax({2, 3})}, 1);
  SpotReading spots;
  if (arch_.centroid_pool) {
    // Inactive pixels (zero in every channel) hold no features and get no
    // weight, as in the submanifold branch.
    const auto value = input.slice(1, 0, 1);
    const auto active = (value != 0).to(value.scalar_type());
    torch::Tensor logits;
    if (arch_.centroid_weighting != CentroidWeighting::kIntensity)
      logits = centroid_conv2_->forwardDense(torch::relu(centroid_conv1_->forwardDense(value)) * active);
    const auto w = centroidWeights(logits, value) * active;
    // Every pixel as a site (inactive ones weigh 0), in the sparse branch's layout.
    const auto batch = input.size(0), pixels = input.size(2) * input.size(3);
    const auto index = torch::arange(batch, torch::TensorOptions().dtype(torch::kLong)).repeat_interleave(pixels);
    spots = readSpots(w.permute({0, 2, 3, 1}).reshape({-1, 1}),
                      input.slice(1, 1, 3).permute({0, 2, 3, 1}).reshape({-1, 2}), active.reshape({-1}), index, batch);
  }
  return head(pooled, spots, {});
}

}  // namespace dss
