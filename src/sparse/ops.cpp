#include "digital_sun_sensor/sparse/ops.h"

#include <torch/autograd.h>

#include <algorithm>
#include <limits>
#include <string>
#include <vector>

#include "blas.h"

namespace dss::sparse {
namespace {

using torch::autograd::AutogradContext;
using torch::autograd::variable_list;

void checkFeatures(const torch::Tensor& features, int rows, const char* op) {
  if (!features.defined() || features.dim() != 2)
    throw std::invalid_argument(std::string(op) + ": features must be a 2-D [sites, channels] tensor");
  if (features.size(0) != rows)
    throw std::invalid_argument(std::string(op) + ": " + std::to_string(features.size(0)) + " feature rows for " +
                                std::to_string(rows) + " active sites");
  if (features.scalar_type() != torch::kFloat && features.scalar_type() != torch::kDouble)
    throw std::invalid_argument(std::string(op) + ": features must be float or double");
}

// Rulebook pairs as saved in an autograd context.
struct Pairs {
  const std::int32_t* in;
  const std::int32_t* out;
  std::vector<std::int64_t> begin;
  int identity;
};

void savePairs(AutogradContext* ctx, const Rulebook& rb) {
  ctx->saved_data["in_rows"] = rb.in_rows;
  ctx->saved_data["out_rows"] = rb.out_rows;
  ctx->saved_data["offset_begin"] = rb.offset_begin;
  ctx->saved_data["identity"] = static_cast<std::int64_t>(rb.identity_offset);
  ctx->saved_data["n_in"] = static_cast<std::int64_t>(rb.input->size());
  ctx->saved_data["n_out"] = static_cast<std::int64_t>(rb.output->size());
}

Pairs loadPairs(AutogradContext* ctx) {
  return {ctx->saved_data["in_rows"].toTensor().data_ptr<std::int32_t>(),
          ctx->saved_data["out_rows"].toTensor().data_ptr<std::int32_t>(),
          ctx->saved_data["offset_begin"].toIntVector(), static_cast<int>(ctx->saved_data["identity"].toInt())};
}

Pairs pairsOf(const Rulebook& rb) {
  return {rb.in_rows.data_ptr<std::int32_t>(), rb.out_rows.data_ptr<std::int32_t>(), rb.offset_begin,
          rb.identity_offset};
}

std::int64_t maxPairsPerOffset(const Pairs& p) {
  std::int64_t m = 0;
  for (std::size_t k = 0; k + 1 < p.begin.size(); ++k) m = std::max(m, p.begin[k + 1] - p.begin[k]);
  return m;
}

// ---- convolution kernels

// Narrow inputs (the stem: 3 channels x 49 offsets) make per-offset GEMMs
// with an inner dimension of 3, mostly overhead. Then the gathered rows of all
// offsets go side by side into one [outputs, k*k*C_in] matrix and one GEMM.
constexpr int kMaxIm2colColumns = 256;

bool useIm2col(const Pairs& p, int c_in) {
  const auto offsets = static_cast<int>(p.begin.size()) - 1;
  return offsets > 1 && offsets * c_in <= kMaxIm2colColumns;
}

template <typename T>
std::vector<T> im2col(const T* x, const Pairs& p, int c_in, std::int64_t n_out) {
  const std::int64_t cols = static_cast<std::int64_t>(p.begin.size() - 1) * c_in;
  std::vector<T> m(static_cast<std::size_t>(n_out * cols), T(0));
  for (std::size_t k = 0; k + 1 < p.begin.size(); ++k)
    for (std::int64_t j = p.begin[k]; j < p.begin[k + 1]; ++j)
      std::copy_n(x + static_cast<std::int64_t>(p.in[j]) * c_in, c_in,
                  m.data() + p.out[j] * cols + static_cast<std::int64_t>(k) * c_in);
  return m;
}

template <typename T>
void convForward(const T* x, const T* w, T* y, const Pairs& p, int c_in, int c_out, std::int64_t n_out) {
  if (useIm2col(p, c_in)) {
    if (n_out == 0) return;
    const int cols = static_cast<int>(p.begin.size() - 1) * c_in;
    const auto m = im2col(x, p, c_in, n_out);
    blas::gemm(false, false, static_cast<int>(n_out), c_out, cols, T(1), m.data(), cols, w, c_out, T(0), y, c_out);
    return;
  }
  const std::int64_t max_pairs = maxPairsPerOffset(p);
  std::vector<T> gathered(static_cast<std::size_t>(max_pairs * c_in));
  std::vector<T> product(static_cast<std::size_t>(max_pairs * c_out));
  for (std::size_t k = 0; k + 1 < p.begin.size(); ++k) {
    const std::int64_t b = p.begin[k], n = p.begin[k + 1] - b;
    if (n == 0) continue;
    const T* wk = w + static_cast<std::int64_t>(k) * c_in * c_out;
    if (static_cast<int>(k) == p.identity) {  // pairs (r, r): no gather, no scatter
      blas::gemm(false, false, static_cast<int>(n), c_out, c_in, T(1), x, c_in, wk, c_out, T(1), y, c_out);
      continue;
    }
    for (std::int64_t j = 0; j < n; ++j)
      std::copy_n(x + static_cast<std::int64_t>(p.in[b + j]) * c_in, c_in, gathered.data() + j * c_in);
    blas::gemm(false, false, static_cast<int>(n), c_out, c_in, T(1), gathered.data(), c_in, wk, c_out, T(0),
               product.data(), c_out);
    for (std::int64_t j = 0; j < n; ++j) {
      T* dst = y + static_cast<std::int64_t>(p.out[b + j]) * c_out;
      const T* src = product.data() + j * c_out;
      for (int c = 0; c < c_out; ++c) dst[c] += src[c];
    }
  }
}

template <typename T>
void convBackward(const T* x, const T* w, const T* dy, T* dx, T* dw, const Pairs& p, int c_in, int c_out,
                  std::int64_t n_out) {
  if (useIm2col(p, c_in)) {
    if (n_out == 0) return;
    const int cols = static_cast<int>(p.begin.size() - 1) * c_in, n = static_cast<int>(n_out);
    if (dw) {
      const auto m = im2col(x, p, c_in, n_out);
      blas::gemm(true, false, cols, c_out, n, T(1), m.data(), cols, dy, c_out, T(0), dw, c_out);
    }
    if (dx) {
      std::vector<T> dm(static_cast<std::size_t>(n_out * cols));
      blas::gemm(false, true, n, cols, c_out, T(1), dy, c_out, w, c_out, T(0), dm.data(), cols);
      for (std::size_t k = 0; k + 1 < p.begin.size(); ++k)
        for (std::int64_t j = p.begin[k]; j < p.begin[k + 1]; ++j) {
          T* dst = dx + static_cast<std::int64_t>(p.in[j]) * c_in;
          const T* src = dm.data() + p.out[j] * static_cast<std::int64_t>(cols) + static_cast<std::int64_t>(k) * c_in;
          for (int c = 0; c < c_in; ++c) dst[c] += src[c];
        }
    }
    return;
  }
  const std::int64_t m = maxPairsPerOffset(p);
  std::vector<T> xg(static_cast<std::size_t>(m * c_in)), gg(static_cast<std::size_t>(m * c_out)),
      dxg(static_cast<std::size_t>(m * c_in));
  for (std::size_t k = 0; k + 1 < p.begin.size(); ++k) {
    const std::int64_t b = p.begin[k], n = p.begin[k + 1] - b;
    const std::int64_t w_off = static_cast<std::int64_t>(k) * c_in * c_out;
    if (n == 0) continue;
    const int ni = static_cast<int>(n);
    if (static_cast<int>(k) == p.identity) {
      if (dw) blas::gemm(true, false, c_in, c_out, ni, T(1), x, c_in, dy, c_out, T(0), dw + w_off, c_out);
      if (dx) blas::gemm(false, true, ni, c_in, c_out, T(1), dy, c_out, w + w_off, c_out, T(1), dx, c_in);
      continue;
    }
    for (std::int64_t j = 0; j < n; ++j)
      std::copy_n(dy + static_cast<std::int64_t>(p.out[b + j]) * c_out, c_out, gg.data() + j * c_out);
    if (dw) {
      for (std::int64_t j = 0; j < n; ++j)
        std::copy_n(x + static_cast<std::int64_t>(p.in[b + j]) * c_in, c_in, xg.data() + j * c_in);
      blas::gemm(true, false, c_in, c_out, ni, T(1), xg.data(), c_in, gg.data(), c_out, T(0), dw + w_off, c_out);
    }
    if (dx) {
      blas::gemm(false, true, ni, c_in, c_out, T(1), gg.data(), c_out, w + w_off, c_out, T(0), dxg.data(), c_in);
      for (std::int64_t j = 0; j < n; ++j) {
        T* dst = dx + static_cast<std::int64_t>(p.in[b + j]) * c_in;
        const T* src = dxg.data() + j * c_in;
        for (int c = 0; c < c_in; ++c) dst[c] += src[c];
      }
    }
  }
}

struct ConvFunction : public torch::autograd::Function<ConvFunction> {
  static torch::Tensor forward(AutogradContext* ctx, torch::Tensor features, torch::Tensor weight, const Rulebook* rb) {
    features = features.contiguous();
    weight = weight.contiguous();
    const int c_in = static_cast<int>(weight.size(1)), c_out = static_cast<int>(weight.size(2));
    auto out = torch::zeros({rb->output->size(), c_out}, features.options());
    AT_DISPATCH_FLOATING_TYPES(features.scalar_type(), "sparseConv", [&] {
      convForward<scalar_t>(features.data_ptr<scalar_t>(), weight.data_ptr<scalar_t>(), out.data_ptr<scalar_t>(),
                            pairsOf(*rb), c_in, c_out, rb->output->size());
    });
    ctx->save_for_backward({features, weight});
    savePairs(ctx, *rb);
    return out;
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const auto saved = ctx->get_saved_variables();
    const torch::Tensor& x = saved[0];
    const torch::Tensor& w = saved[1];
    const torch::Tensor dy = grads[0].contiguous();
    const int c_in = static_cast<int>(w.size(1)), c_out = static_cast<int>(w.size(2));
    torch::Tensor dx, dw;
    if (ctx->needs_input_grad(0)) dx = torch::zeros_like(x);
    if (ctx->needs_input_grad(1)) dw = torch::zeros_like(w);
    const Pairs p = loadPairs(ctx);
    AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "sparseConvBackward", [&] {
      convBackward<scalar_t>(x.data_ptr<scalar_t>(), w.data_ptr<scalar_t>(), dy.data_ptr<scalar_t>(),
                             dx.defined() ? dx.data_ptr<scalar_t>() : nullptr,
                             dw.defined() ? dw.data_ptr<scalar_t>() : nullptr, p, c_in, c_out, dy.size(0));
    });
    return {dx, dw, torch::Tensor()};
  }
};

// ---- pooling over rulebook neighbourhoods

struct MaxPoolFunction : public torch::autograd::Function<MaxPoolFunction> {
  static torch::Tensor forward(AutogradContext* ctx, torch::Tensor features, const Rulebook* rb) {
    features = features.contiguous();
    const int c = static_cast<int>(features.size(1));
    const std::int64_t n_out = rb->output->size();
    auto out = torch::full({n_out, c}, -std::numeric_limits<double>::infinity(), features.options());
    auto arg = torch::full({n_out, c}, -1, torch::kInt32);
    const Pairs p = pairsOf(*rb);
    AT_DISPATCH_FLOATING_TYPES(features.scalar_type(), "sparseMaxPool", [&] {
      const scalar_t* x = features.data_ptr<scalar_t>();
      scalar_t* y = out.data_ptr<scalar_t>();
      std::int32_t* a = arg.data_ptr<std::int32_t>();
      for (std::int64_t j = 0; j < p.begin.back(); ++j) {
        const std::int64_t o = p.out[j] * static_cast<std::int64_t>(c), i = p.in[j];
        for (int ch = 0; ch < c; ++ch)
          if (x[i * c + ch] > y[o + ch]) {
            y[o + ch] = x[i * c + ch];
            a[o + ch] = static_cast<std::int32_t>(i);
          }
      }
    });
    ctx->saved_data["arg"] = arg;
    ctx->saved_data["n_in"] = static_cast<std::int64_t>(features.size(0));
    return out;
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const torch::Tensor arg = ctx->saved_data["arg"].toTensor();
    const torch::Tensor dy = grads[0].contiguous();
    const int c = static_cast<int>(dy.size(1));
    auto dx = torch::zeros({ctx->saved_data["n_in"].toInt(), c}, dy.options());
    AT_DISPATCH_FLOATING_TYPES(dy.scalar_type(), "sparseMaxPoolBackward", [&] {
      const scalar_t* g = dy.data_ptr<scalar_t>();
      scalar_t* d = dx.data_ptr<scalar_t>();
      const std::int32_t* a = arg.data_ptr<std::int32_t>();
      for (std::int64_t e = 0; e < arg.numel(); ++e)
        if (a[e] >= 0) d[a[e] * static_cast<std::int64_t>(c) + e % c] += g[e];
    });
    return {dx, torch::Tensor()};
  }
};

std::vector<std::int32_t> pairsPerOutput(const Pairs& p, std::int64_t n_out) {
  std::vector<std::int32_t> count(static_cast<std::size_t>(n_out), 0);
  for (std::int64_t j = 0; j < p.begin.back(); ++j) ++count[static_cast<std::size_t>(p.out[j])];
  return count;
}

struct AvgPoolFunction : public torch::autograd::Function<AvgPoolFunction> {
  static torch::Tensor forward(AutogradContext* ctx, torch::Tensor features, const Rulebook* rb) {
    features = features.contiguous();
    const int c = static_cast<int>(features.size(1));
    auto out = torch::zeros({rb->output->size(), c}, features.options());
    const Pairs p = pairsOf(*rb);
    const auto count = pairsPerOutput(p, rb->output->size());
    AT_DISPATCH_FLOATING_TYPES(features.scalar_type(), "sparseAvgPool", [&] {
      const scalar_t* x = features.data_ptr<scalar_t>();
      scalar_t* y = out.data_ptr<scalar_t>();
      for (std::int64_t j = 0; j < p.begin.back(); ++j) {
        const scalar_t scale = scalar_t(1) / count[static_cast<std::size_t>(p.out[j])];
        for (int ch = 0; ch < c; ++ch)
          y[p.out[j] * static_cast<std::int64_t>(c) + ch] += scale * x[p.in[j] * static_cast<std::int64_t>(c) + ch];
      }
    });
    savePairs(ctx, *rb);
    return out;
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const torch::Tensor dy = grads[0].contiguous();
    const int c = static_cast<int>(dy.size(1));
    const Pairs p = loadPairs(ctx);
    const auto count = pairsPerOutput(p, ctx->saved_data["n_out"].toInt());
    auto dx = torch::zeros({ctx->saved_data["n_in"].toInt(), c}, dy.options());
    AT_DISPATCH_FLOATING_TYPES(dy.scalar_type(), "sparseAvgPoolBackward", [&] {
      const scalar_t* g = dy.data_ptr<scalar_t>();
      scalar_t* d = dx.data_ptr<scalar_t>();
      for (std::int64_t j = 0; j < p.begin.back(); ++j) {
        const scalar_t scale = scalar_t(1) / count[static_cast<std::size_t>(p.out[j])];
        for (int ch = 0; ch < c; ++ch)
          d[p.in[j] * static_cast<std::int64_t>(c) + ch] += scale * g[p.out[j] * static_cast<std::int64_t>(c) + ch];
      }
    });
    return {dx, torch::Tensor()};
  }
};

// ---- per-image pooling and densification

struct GlobalMaxFunction : public torch::autograd::Function<GlobalMaxFunction> {
  static torch::Tensor forward(AutogradContext* ctx, torch::Tensor features, const SiteSet* sites) {
    features = features.contiguous();
    const int c = static_cast<int>(features.size(1));
    const std::int64_t batch = sites->batchSize();
    auto out = torch::zeros({batch, c}, features.options());
    auto arg = torch::full({batch, c}, -1, torch::kInt32);
    AT_DISPATCH_FLOATING_TYPES(features.scalar_type(), "globalMaxPool", [&] {
      const scalar_t* x = features.data_ptr<scalar_t>();
      scalar_t* y = out.data_ptr<scalar_t>();
      std::int32_t* a = arg.data_ptr<std::int32_t>();
      for (int i = 0; i < sites->size(); ++i) {
        const std::int64_t o = sites->site(i).batch * static_cast<std::int64_t>(c);
        for (int ch = 0; ch < c; ++ch)
          if (a[o + ch] < 0 || x[i * static_cast<std::int64_t>(c) + ch] > y[o + ch]) {
            y[o + ch] = x[i * static_cast<std::int64_t>(c) + ch];
            a[o + ch] = i;
          }
      }
    });
    ctx->saved_data["arg"] = arg;
    ctx->saved_data["n_in"] = static_cast<std::int64_t>(features.size(0));
    return out;
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    return {MaxPoolFunction::backward(ctx, grads)[0], torch::Tensor()};
  }
};

struct ToDenseFunction : public torch::autograd::Function<ToDenseFunction> {
  static torch::Tensor forward(AutogradContext* ctx, torch::Tensor features, const SiteSet* sites) {
    features = features.contiguous();
    const std::int64_t c = features.size(1), h = sites->height(), w = sites->width();
    auto out = torch::zeros({sites->batchSize(), c, h, w}, features.options());
    std::vector<std::int64_t> index(static_cast<std::size_t>(sites->size()));
    for (int i = 0; i < sites->size(); ++i) {
      const Site& s = sites->site(i);
      index[static_cast<std::size_t>(i)] = (s.batch * c * h + s.y) * w + s.x;  // channel 0 of the site
    }
    AT_DISPATCH_FLOATING_TYPES(features.scalar_type(), "toDense", [&] {
      const scalar_t* x = features.data_ptr<scalar_t>();
      scalar_t* y = out.data_ptr<scalar_t>();
      for (std::size_t i = 0; i < index.size(); ++i)
        for (std::int64_t ch = 0; ch < c; ++ch) y[index[i] + ch * h * w] = x[static_cast<std::int64_t>(i) * c + ch];
    });
    ctx->saved_data["index"] = torch::tensor(index, torch::kInt64);
    return out;
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const torch::Tensor index = ctx->saved_data["index"].toTensor();
    const torch::Tensor dy = grads[0].contiguous();
    const std::int64_t c = dy.size(1), hw = dy.size(2) * dy.size(3);
    auto dx = torch::empty({index.size(0), c}, dy.options());
    AT_DISPATCH_FLOATING_TYPES(dy.scalar_type(), "toDenseBackward", [&] {
      const scalar_t* g = dy.data_ptr<scalar_t>();
      scalar_t* d = dx.data_ptr<scalar_t>();
      const std::int64_t* idx = index.data_ptr<std::int64_t>();
      for (std::int64_t i = 0; i < index.size(0); ++i)
        for (std::int64_t ch = 0; ch < c; ++ch) d[i * c + ch] = g[idx[i] + ch * hw];
    });
    return {dx, torch::Tensor()};
  }
};

}  // namespace

torch::Tensor sparseConv(const torch::Tensor& features, const torch::Tensor& weight, const Rulebook& rulebook) {
  checkFeatures(features, rulebook.input->size(), "sparseConv");
  if (weight.dim() != 3 || weight.size(0) != rulebook.numOffsets() || weight.size(1) != features.size(1))
    throw std::invalid_argument("sparseConv: weight must be [" + std::to_string(rulebook.numOffsets()) + ", " +
                                std::to_string(features.size(1)) + ", C_out], got " + std::to_string(weight.dim()) +
                                "-D " + std::to_string(weight.size(0)) + "x...");
  if (weight.scalar_type() != features.scalar_type())
    throw std::invalid_argument("sparseConv: weight and features differ in dtype");
  return ConvFunction::apply(features, weight, &rulebook);
}

torch::Tensor sparseMaxPool(const torch::Tensor& features, const Rulebook& rulebook) {
  checkFeatures(features, rulebook.input->size(), "sparseMaxPool");
  return MaxPoolFunction::apply(features, &rulebook);
}

torch::Tensor sparseAvgPool(const torch::Tensor& features, const Rulebook& rulebook) {
  checkFeatures(features, rulebook.input->size(), "sparseAvgPool");
  return AvgPoolFunction::apply(features, &rulebook);
}

torch::Tensor batchIndex(const SiteSet& sites) {
  auto index = torch::empty({sites.size()}, torch::kInt64);
  auto* p = index.data_ptr<std::int64_t>();
  for (int i = 0; i < sites.size(); ++i) p[i] = sites.site(i).batch;
  return index;
}

torch::Tensor globalAvgPool(const torch::Tensor& features, const SiteSet& sites) {
  checkFeatures(features, sites.size(), "globalAvgPool");
  // index_add is differentiable in ATen; a division by the per-image count makes the mean.
  const auto counts = sites.countsPerImage();
  auto inverse = torch::empty({sites.batchSize(), 1}, features.options());
  AT_DISPATCH_FLOATING_TYPES(features.scalar_type(), "globalAvgPool", [&] {
    for (int b = 0; b < sites.batchSize(); ++b)
      inverse.data_ptr<scalar_t>()[b] =
          counts[static_cast<std::size_t>(b)] > 0 ? scalar_t(1) / counts[static_cast<std::size_t>(b)] : scalar_t(0);
  });
  return indexSum(features, batchIndex(sites), sites.batchSize()) * inverse;
}

torch::Tensor indexSum(const torch::Tensor& values, const torch::Tensor& index, std::int64_t rows) {
  TORCH_CHECK(values.dim() == 2 && index.dim() == 1 && index.size(0) == values.size(0),
              "indexSum: values [N, C] and index [N] expected");
  const std::int64_t channels = values.size(1);
  // Element (i, c) adds to (index[i], c) in order of i, as the row-wise sum does.
  const torch::Tensor flat_index =
      channels == 1 ? index : (index.unsqueeze(1) * channels + torch::arange(channels, index.options())).reshape({-1});
  return torch::zeros({rows * channels}, values.options())
      .index_add(0, flat_index, values.reshape({-1}))
      .view({rows, channels});
}

torch::Tensor globalMaxPool(const torch::Tensor& features, const SiteSet& sites) {
  checkFeatures(features, sites.size(), "globalMaxPool");
  return GlobalMaxFunction::apply(features, &sites);
}

torch::Tensor toDense(const torch::Tensor& features, const SiteSet& sites) {
  checkFeatures(features, sites.size(), "toDense");
  return ToDenseFunction::apply(features, &sites);
}

}  // namespace dss::sparse
