// The backbone's layers: sparse convolutions (submanifold or strided) and
// residual blocks over them, each also runnable densely with the same weights.
#pragma once

#include <torch/nn/module.h>
#include <torch/nn/modules/batchnorm.h>

#include "digital_sun_sensor/sparse/sparse_tensor.h"

namespace dss {

// Submanifold (stride 1, output sites = input sites) or strided sparse
// convolution; weight [k*k, C_in, C_out].
class SparseConvImpl : public torch::nn::Module {
 public:
  SparseConvImpl(int in_channels, int out_channels, int kernel_size, int stride, bool bias);
  sparse::SparseTensor forward(const sparse::SparseTensor& x);
  // Same weights as a dense torch::conv2d over a [B, C, H, W] map.
  torch::Tensor forwardDense(const torch::Tensor& x);
  // 1x1 stride-s shortcut on the sites of the k x k stride-s main path.
  sparse::SparseTensor forwardShortcut(const sparse::SparseTensor& x, int main_kernel_size);

  torch::Tensor weight, bias;
  int kernel_size, stride;
};

class ResidualBlockImpl : public torch::nn::Module {
 public:
  ResidualBlockImpl(int in_channels, int out_channels, int stride, bool batch_norm);
  sparse::SparseTensor forward(const sparse::SparseTensor& x);
  torch::Tensor forwardDense(const torch::Tensor& x);

 private:
  torch::Tensor norm(torch::nn::BatchNorm1d& bn, const torch::Tensor& f);
  torch::Tensor normDense(torch::nn::BatchNorm1d& bn, const torch::Tensor& f);
  std::shared_ptr<SparseConvImpl> conv1_, conv2_, shortcut_;
  torch::nn::BatchNorm1d bn1_{nullptr}, bn2_{nullptr};
  int stride_;
};

}  // namespace dss
