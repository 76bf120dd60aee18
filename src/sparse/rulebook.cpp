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

}  // namespace

std::shared_ptr<const Rulebook> submanifoldRulebook(std::shared_ptr<const SiteSet> input, int kernel_size) {
  if (kernel_size < 1 || kernel_size % 2 == 0)
    throw std::invalid_argument("submanifold convolution needs an odd kernel size, got " + std::to_string(kernel_size));
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
  // Input i reaches output o through offset d when s*o = i + p - d: only the
  // offsets congruent to i + p modulo s, at most ceil(k/s)^2 of them.
  struct Reach {
    int offset;
    Site out;
  };
  std::vector<Reach> reaches;
  auto reachesOf = [&](const Site& site) {
    reaches.clear();
    for (int dy = (site.y + padding) % stride; dy < k; dy += stride) {
      const int oy = (site.y + padding - dy) / stride;
      if (oy < 0 || oy >= out_h || site.y + padding - dy < 0) continue;
      for (int dx = (site.x + padding) % stride; dx < k; dx += stride) {
        const int ox = (site.x + padding - dx) / stride;
        if (ox < 0 || ox >= out_w || site.x + padding - dx < 0) continue;
        reaches.push_back({dy * k + dx, {site.batch, oy, ox}});
      }
    }
  };
  // Distinct output sites through a hash set of packed keys; sorting the packed
  // keys orders them by (batch, y, x): deterministic and cache-friendly.
  const int per_input = ((k + stride - 1) / stride) * ((k + stride - 1) / stride);
  std::uint64_t capacity = 16;
  while (capacity < 2 * static_cast<std::uint64_t>(input->size()) * per_input) capacity *= 2;
  constexpr std::uint64_t kEmpty = ~std::uint64_t{0};
  std::vector<std::uint64_t> slots(capacity, kEmpty), keys;
  for (const Site& site : input->sites()) {
    reachesOf(site);
    for (const Reach& r : reaches) {
      const std::uint64_t key = SiteSet::packKey(r.out);
      std::uint64_t slot = (key * 0x9E3779B97F4A7C15ULL) >> 20 & (capacity - 1);
      while (slots[slot] != kEmpty && slots[slot] != key) slot = (slot + 1) & (capacity - 1);
      if (slots[slot] == kEmpty) {
        slots[slot] = key;
        keys.push_back(key);
      }
    }
  }
  std::sort(keys.begin(), keys.end());
  std::vector<Site> outputs;
  outputs.reserve(keys.size());
  for (std::uint64_t key : keys) outputs.push_back(SiteSet::unpackKey(key));

  auto rb = std::make_shared<Rulebook>();
  rb->kernel_size = k;
  rb->stride = stride;
  rb->padding = padding;
  rb->input = input;
  auto output = std::make_shared<SiteSet>(input->batchSize(), out_h, out_w, std::move(outputs));
  rb->output = output;
  std::vector<std::vector<std::int32_t>> in_by_offset(static_cast<std::size_t>(k * k)),
      out_by_offset(static_cast<std::size_t>(k * k));
  for (int i = 0; i < input->size(); ++i) {
    reachesOf(input->site(i));
    for (const Reach& r : reaches) {
      in_by_offset[static_cast<std::size_t>(r.offset)].push_back(i);
      out_by_offset[static_cast<std::size_t>(r.offset)].push_back(output->find(r.out.batch, r.out.y, r.out.x));
    }
  }
  std::vector<std::int32_t> in_rows, out_rows;
  rb->offset_begin.push_back(0);
  for (int d = 0; d < k * k; ++d) {
    const auto& ins = in_by_offset[static_cast<std::size_t>(d)];
    const auto& outs = out_by_offset[static_cast<std::size_t>(d)];
    in_rows.insert(in_rows.end(), ins.begin(), ins.end());
    out_rows.insert(out_rows.end(), outs.begin(), outs.end());
    rb->offset_begin.push_back(static_cast<std::int64_t>(in_rows.size()));
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
