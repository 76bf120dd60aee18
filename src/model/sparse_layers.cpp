#include "digital_sun_sensor/model/sparse_layers.h"

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

}  // namespace dss
