#include "digital_sun_sensor/model/sscnn.h"

#include <torch/nn/functional/activation.h>
#include <torch/nn/functional/conv.h>
#include <torch/nn/functional/pooling.h>

#include <cmath>

#include "digital_sun_sensor/sparse/ops.h"

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
    centroid_conv1_ = register_module(
        "centroid_conv1", std::make_shared<SparseConvImpl>(1, arch.centroid_width, 3, 1, true));
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
  const int head_in = 2 * channels + (arch.centroid_pool ? 2 : 0), class_hidden = arch.head_hidden.back();
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

SscnnOutput SscnnNetImpl::head(const torch::Tensor& pooled, const torch::Tensor& centroid) {
  // Pooled features of a network without batch norm grow with depth and
  // brightness; normalized, the MLP starts in its working range.
  const torch::Tensor normed = head_norm_->forward(pooled);
  torch::Tensor h = centroid.defined() ? torch::cat({normed, centroid}, 1) : normed;
  SscnnOutput result;
  result.class_logits = class_output_->forward(torch::silu(class_hidden_->forward(h)));
  for (auto& layer : mlp_) h = torch::silu(layer->forward(h));
  result.angles = arch_.residual_scale * output_->forward(h);
  if (centroid.defined())
    result.angles = result.angles + centroid * centroid_prior_ +
                    arch_.residual_scale * centroid_skip_->forward(monomials(centroid));
  result.log_variance = variance_->forward(h.detach());
  return result;
}

SscnnOutput SscnnNetImpl::forward(const SparseTensor& input) {
  SparseTensor x = stem_->forward(input);
  x = x.with(torch::relu(x.features));
  if (arch_.stem_max_pool) {
    auto rb = x.rulebook(RulebookCache::Kind::kStrided, 3, 2, 1);
    x = {sparse::sparseMaxPool(x.features, *rb), rb->output, x.rulebooks};
  }
  for (auto& block : blocks_) x = block->forward(x);
  const torch::Tensor pooled =
      torch::cat({sparse::globalAvgPool(x.features, *x.sites), sparse::globalMaxPool(x.features, *x.sites)}, 1);
  torch::Tensor centroid;
  if (arch_.centroid_pool) {
    // Learned weights w >= 0 per input site from the local pixel values only
    // (translation-equivariant: no position-dependent bias); centroid =
    // sum(w xy) / sum(w) per image.
    SparseTensor c = centroid_conv1_->forward(input.with(input.features.slice(1, 0, 1).contiguous()));
    c = centroid_conv2_->forward(c.with(torch::relu(c.features)));
    const torch::Tensor w = torch::softplus(c.features);
    const torch::Tensor index = sparse::batchIndex(*input.sites);
    const auto batch = input.sites->batchSize();
    auto num = torch::zeros({batch, 2}, w.options()).index_add(0, index, w * input.features.slice(1, 1, 3));
    auto den = torch::zeros({batch, 1}, w.options()).index_add(0, index, w);
    centroid = num / (den + 1e-6);
  }
  return head(pooled, centroid);
}

SscnnOutput SscnnNetImpl::forwardDense(const torch::Tensor& input) {
  auto x = torch::relu(stem_->forwardDense(input));
  if (arch_.stem_max_pool) x = F::max_pool2d(x, F::MaxPool2dFuncOptions(3).stride(2).padding(1));
  for (auto& block : blocks_) x = block->forwardDense(x);
  const torch::Tensor pooled = torch::cat({x.mean({2, 3}), x.amax({2, 3})}, 1);
  torch::Tensor centroid;
  if (arch_.centroid_pool) {
    // Inactive pixels (zero in every channel) hold no features and get no
    // weight, as in the submanifold branch.
    const auto value = input.slice(1, 0, 1);
    const auto active = (value != 0).to(value.scalar_type());
    const auto c = torch::relu(centroid_conv1_->forwardDense(value)) * active;
    const auto w = torch::softplus(centroid_conv2_->forwardDense(c)) * active;
    centroid = (w * input.slice(1, 1, 3)).sum({2, 3}) / (w.sum({2, 3}) + 1e-6);
  }
  return head(pooled, centroid);
}

}  // namespace dss
