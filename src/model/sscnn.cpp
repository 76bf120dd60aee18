#include "digital_sun_sensor/model/sscnn.h"

#include <torch/nn/functional/activation.h>
#include <torch/nn/functional/conv.h>
#include <torch/nn/functional/pooling.h>

#include <algorithm>
#include <cmath>

#include "digital_sun_sensor/sparse/ops.h"

namespace dss {

using sparse::RulebookCache;
using sparse::SparseTensor;
namespace F = torch::nn::functional;

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
  pooled_width_ = 2 * channels;
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
  // The geometric head's variance also reads the solve's log variance per
  // axis (how the read spots constrain the angles), as two more inputs.
  const bool solved = arch.geometric_head || arch.pattern_head;  // the variance reads the solve's too
  variance_ = register_module("variance", torch::nn::Linear(features + (solved ? 2 : 0), 2));
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
  if (arch.geometric_head) {
    geometry_ = register_module(
        "geometry", SensorGeometry(arch.geometric_apertures, arch.geometric_groups, arch.geometric_air_above_exit_um));
    const int monomials = (arch.centroid_degree + 1) * (arch.centroid_degree + 2) / 2 - 1;
    geometric_correction_ = register_module("geometric_correction", torch::nn::Linear(monomials, 2));
  }
  const int head_in = 2 * channels + (arch.centroid_pool ? 2 : 0) + (class_resolved ? 4 : 0);
  const int class_hidden = arch.head_hidden.back();
  class_hidden_ = register_module("class_hidden", torch::nn::Linear(head_in, class_hidden));
  class_output_ = register_module("class_output", torch::nn::Linear(class_hidden, arch.num_classes));
  torch::NoGradGuard no_grad;
  if (geometric_correction_) {  // the geometry's angles as they are, at the start
    geometric_correction_->weight.zero_();
    geometric_correction_->bias.zero_();
  }
  output_->weight.zero_();  // start with angle corrections of zero...
  output_->bias.zero_();
  variance_->weight.mul_(0.1);  // ...and unit variance
  variance_->bias.zero_();
  if (solved) {  // ...or the solve's, per axis
    variance_->weight.slice(1, features, features + 2).zero_();
    variance_->weight[0][features] = 1.0;
    variance_->weight[1][features + 1] = 1.0;
  }
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

std::tuple<torch::Tensor, double, double> SscnnNetImpl::geometricPriorCopy() const {
  if (!geometric_prior_.defined()) return {torch::Tensor(), 1.0, 1.0};
  return {geometric_prior_.squeeze(0).clone(), geometric_prior_extent_[0].item<double>(),
          geometric_prior_extent_[1].item<double>()};
}

void SscnnNetImpl::initGeometry(const GeometryDesign& design) {
  if (geometry_) geometry_->setDesign(design);
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

bool SscnnNetImpl::backboneNeeded() const {
  if (arch_.pattern_head) return false;   // its forward never runs the network
  if (!arch_.centroid_pool) return true;  // the angles read the features
  // Feature corrections of zero weight (a geometric head as created: the
  // family models) add their bias alone, whatever the features.
  if (arch_.feature_corrections && output_->weight.count_nonzero().item<std::int64_t>() != 0) return true;
  if (arch_.latticeHead() && arch_.lattice_resolve == LatticeResolve::kClass) return true;  // pitches from the class
  if (!arch_.apertureClassLattice() && !arch_.geometric_head) return true;  // the class is the classifier's
  // The geometric head's variance also reads the solve's log variance (its last two inputs).
  const std::int64_t features = variance_->weight.size(1) - (arch_.geometric_head ? 2 : 0);
  return variance_->weight.slice(1, 0, features).count_nonzero().item<std::int64_t>() != 0;
}

bool SscnnNetImpl::skipsBackbone() const {
  return skip_unused_backbone_ && !is_training() && !torch::GradMode::is_enabled() && !backboneNeeded();
}

std::int64_t SscnnNetImpl::parameterCount() const {
  std::int64_t n = 0;
  for (const auto& p : parameters()) n += p.numel();
  return n;
}

SscnnOutput SscnnNetImpl::forward(const SparseTensor& input, const torch::Tensor& known_classes,
                                  const torch::Tensor& known_angles) {
  if (arch_.pattern_head) return patternForward(input, known_angles);
  torch::Tensor pooled;
  if (skipsBackbone()) {
    pooled = torch::zeros({input.sites->batchSize(), pooled_width_}, input.features.options());
  } else {
    SparseTensor x = stem_->forward(input);
    x = x.with(torch::relu(x.features));
    if (arch_.stem_max_pool) {
      auto rb = x.rulebook(RulebookCache::Kind::kStrided, 3, 2, 1);
      x = {sparse::sparseMaxPool(x.features, *rb), rb->output, x.rulebooks};
    }
    for (auto& block : blocks_) x = block->forward(x);
    pooled = torch::cat({sparse::globalAvgPool(x.features, *x.sites), sparse::globalMaxPool(x.features, *x.sites)}, 1);
  }
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
    const torch::Tensor w = centroidWeights(logits, value), xy = input.features.slice(1, 1, 3);
    const torch::Tensor index = sparse::batchIndex(*input.sites);
    spots = readSpots(w, xy, torch::ones({input.features.size(0)}, input.features.options()), index,
                      input.sites->batchSize());
    if (arch_.geometric_head) {
      SscnnOutput out = head(pooled, spots, known_classes);
      solveAngles(out, w, xy, index, input.sites->batchSize(), known_angles);
      return out;
    }
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
    const auto site_w = w.permute({0, 2, 3, 1}).reshape({-1, 1});
    const auto xy = input.slice(1, 1, 3).permute({0, 2, 3, 1}).reshape({-1, 2});
    spots = readSpots(site_w, xy, active.reshape({-1}), index, batch);
    if (arch_.geometric_head) {
      SscnnOutput out = head(pooled, spots, {});
      solveAngles(out, site_w, xy, index, batch, {});
      return out;
    }
  }
  return head(pooled, spots, {});
}

}  // namespace dss
