#include "digital_sun_sensor/sparse/rulebook.h"

#include <algorithm>
#include <string>

namespace dss::sparse {
namespace {

torch::Tensor toTensor(const std::vector<std::int32_t>& values) {
  auto t = torch::empty({static_cast<std::int64_t>(values.size())}, torch::kInt32);
  std::copy(values.begin(), values.end(), t.data_ptr<std::int32_t>());
  return t;
}

// Floor division for possibly negative numerators.
int floorDiv(int a, int b) { return (a >= 0) ? a / b : -((-a + b - 1) / b); }

}  // namespace

std::shared_ptr<const Rulebook> submanifoldRulebook(std::shared_ptr<const SiteSet> input, int kernel_size) {
  if (kernel_size < 1 || kernel_size % 2 == 0)
    throw std::invalid_argument("submanifold convolution needs an odd kernel size, got " +
                                std::to_string(kernel_size));
  auto rb = std::make_shared<Rulebook>();
  rb->kernel_size = kernel_size;
  rb->padding = kernel_size / 2;
  rb->input = input;
  rb->output = input;
  const int k = kernel_size, half = k / 2, n = input->size();
  std::vector<std::int32_t> in_rows, out_rows;
  in_rows.reserve(static_cast<std::size_t>(n) * 3);
  out_rows.reserve(static_cast<std::size_t>(n) * 3);
  rb->offset_begin.push_back(0);
  for (int dy = 0; dy < k; ++dy) {
    for (int dx = 0; dx < k; ++dx) {
      for (int o = 0; o < n; ++o) {
        const Site& s = input->site(o);
        const int i = input->find(s.batch, s.y + dy - half, s.x + dx - half);
        if (i < 0) continue;
        in_rows.push_back(i);
        out_rows.push_back(o);
      }
      rb->offset_begin.push_back(static_cast<std::int64_t>(in_rows.size()));
    }
  }
  rb->identity_offset = half * k + half;
  rb->in_rows = toTensor(in_rows);
  rb->out_rows = toTensor(out_rows);
  return rb;
}

std::shared_ptr<const Rulebook> stridedRulebook(std::shared_ptr<const SiteSet> input, int kernel_size, int stride,
                                                int padding) {
  if (kernel_size < 1 || stride < 1 || padding < 0 || padding >= kernel_size)
    throw std::invalid_argument("strided sparse convolution: bad geometry kernel " + std::to_string(kernel_size) +
                                " stride " + std::to_string(stride) + " padding " + std::to_string(padding));
  const int out_h = (input->height() + 2 * padding - kernel_size) / stride + 1;
  const int out_w = (input->width() + 2 * padding - kernel_size) / stride + 1;
  if (out_h < 1 || out_w < 1)
    throw std::invalid_argument("strided sparse convolution: kernel " + std::to_string(kernel_size) +
                                " larger than the padded " + std::to_string(input->height()) + "x" +
                                std::to_string(input->width()) + " input");
  const int k = kernel_size;
  // Output o is reached by input i through offset d when s*o = i + p - d.
  auto reach = [&](const Site& s, int dy, int dx, Site* out) {
    const int ny = s.y + padding - dy, nx = s.x + padding - dx;
    if (ny % stride != 0 || nx % stride != 0) return false;
    out->batch = s.batch;
    out->y = floorDiv(ny, stride);
    out->x = floorDiv(nx, stride);
    return out->y >= 0 && out->y < out_h && out->x >= 0 && out->x < out_w;
  };
  std::vector<Site> outputs;
  for (const Site& s : input->sites())
    for (int dy = 0; dy < k; ++dy)
      for (int dx = 0; dx < k; ++dx) {
        Site o;
        if (reach(s, dy, dx, &o)) outputs.push_back(o);
      }
  // Sorted (batch, y, x): deterministic and cache-friendly row order.
  auto less = [](const Site& a, const Site& b) {
    return std::tie(a.batch, a.y, a.x) < std::tie(b.batch, b.y, b.x);
  };
  auto equal = [](const Site& a, const Site& b) { return a.batch == b.batch && a.y == b.y && a.x == b.x; };
  std::sort(outputs.begin(), outputs.end(), less);
  outputs.erase(std::unique(outputs.begin(), outputs.end(), equal), outputs.end());

  auto rb = std::make_shared<Rulebook>();
  rb->kernel_size = k;
  rb->stride = stride;
  rb->padding = padding;
  rb->input = input;
  auto output = std::make_shared<SiteSet>(input->batchSize(), out_h, out_w, std::move(outputs));
  rb->output = output;
  std::vector<std::int32_t> in_rows, out_rows;
  rb->offset_begin.push_back(0);
  for (int dy = 0; dy < k; ++dy) {
    for (int dx = 0; dx < k; ++dx) {
      for (int i = 0; i < input->size(); ++i) {
        Site o;
        if (!reach(input->site(i), dy, dx, &o)) continue;
        in_rows.push_back(i);
        out_rows.push_back(output->find(o.batch, o.y, o.x));
      }
      rb->offset_begin.push_back(static_cast<std::int64_t>(in_rows.size()));
    }
  }
  rb->in_rows = toTensor(in_rows);
  rb->out_rows = toTensor(out_rows);
  return rb;
}

std::shared_ptr<const Rulebook> singleOffsetRulebook(const Rulebook& rulebook, int offset) {
  if (offset < 0 || offset >= rulebook.numOffsets())
    throw std::invalid_argument("singleOffsetRulebook: offset " + std::to_string(offset) + " out of range");
  auto rb = std::make_shared<Rulebook>();
  rb->kernel_size = 1;
  rb->stride = rulebook.stride;
  rb->input = rulebook.input;
  rb->output = rulebook.output;
  const auto begin = rulebook.offset_begin[static_cast<std::size_t>(offset)];
  const auto end = rulebook.offset_begin[static_cast<std::size_t>(offset) + 1];
  rb->in_rows = rulebook.in_rows.slice(0, begin, end).clone();
  rb->out_rows = rulebook.out_rows.slice(0, begin, end).clone();
  rb->offset_begin = {0, end - begin};
  if (offset == rulebook.identity_offset) rb->identity_offset = 0;
  return rb;
}

std::shared_ptr<const Rulebook> RulebookCache::get(const std::shared_ptr<const SiteSet>& input, Kind kind,
                                                   int kernel_size, int stride, int padding) {
  const Key key{input.get(), static_cast<int>(kind), kernel_size, stride, padding};
  std::lock_guard<std::mutex> lock(mutex_);
  auto it = cache_.find(key);
  if (it != cache_.end()) return it->second;
  std::shared_ptr<const Rulebook> rb;
  switch (kind) {
    case Kind::kSubmanifold:
      rb = submanifoldRulebook(input, kernel_size);
      break;
    case Kind::kStrided:
      rb = stridedRulebook(input, kernel_size, stride, padding);
      break;
    case Kind::kShortcut: {
      // 1x1 stride-s convolution on the sites of the k x k stride-s pad-k/2
      // main path: the centre offset of that rulebook.
      const Key main_key{input.get(), static_cast<int>(Kind::kStrided), kernel_size, stride, kernel_size / 2};
      auto main = cache_.find(main_key);
      std::shared_ptr<const Rulebook> main_rb =
          main != cache_.end() ? main->second : stridedRulebook(input, kernel_size, stride, kernel_size / 2);
      cache_[main_key] = main_rb;
      rb = singleOffsetRulebook(*main_rb, (kernel_size / 2) * kernel_size + kernel_size / 2);
      break;
    }
  }
  cache_[key] = rb;
  return rb;
}

}  // namespace dss::sparse
