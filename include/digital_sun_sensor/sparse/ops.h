// Differentiable sparse operations (torch::autograd::Functions with their own
// backward), on feature matrices [sites, channels] in float or double.
//   conv:   Y[out_k] += X[in_k] W_k              (gather - GEMM - scatter)
//   dW_k = X[in_k]^T dY[out_k],   dX[in_k] += dY[out_k] W_k^T
// GEMMs go to OpenBLAS. Feature rows follow the rulebook's / site set's order.
#pragma once

#include "digital_sun_sensor/sparse/rulebook.h"

namespace dss::sparse {

// weight [k*k, C_in, C_out]; returns features on rulebook.output.
torch::Tensor sparseConv(const torch::Tensor& features, const torch::Tensor& weight, const Rulebook& rulebook);

// Max / mean over the active inputs each output site gathers (inactive sites
// do not count: a sparse mean, not a zero-padded one).
torch::Tensor sparseMaxPool(const torch::Tensor& features, const Rulebook& rulebook);
torch::Tensor sparseAvgPool(const torch::Tensor& features, const Rulebook& rulebook);

// Per-image pooling over all sites -> [batch, C]; an image without sites gives zeros.
torch::Tensor globalAvgPool(const torch::Tensor& features, const SiteSet& sites);
torch::Tensor globalMaxPool(const torch::Tensor& features, const SiteSet& sites);

// -> dense [batch, C, height, width], zeros at inactive sites.
torch::Tensor toDense(const torch::Tensor& features, const SiteSet& sites);

// Batch index of every site as an int64 tensor [sites] (for index_add pooling).
torch::Tensor batchIndex(const SiteSet& sites);

// torch::zeros({rows, C}).index_add(0, index, values) for values [N, C] and
// index [N] (int64), the same sums to the bit, differentiable in values:
// through one index_add over the flattened matrix. ATen 1.13 adds a
// matrix's rows one dispatched add per row (~90 us for 2900 sites of three
// channels, against ~20 us flattened).
torch::Tensor indexSum(const torch::Tensor& values, const torch::Tensor& index, std::int64_t rows);

}  // namespace dss::sparse
