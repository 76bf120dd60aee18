// Rulebooks of sparse convolutions: for each kernel offset, the (input row,
// output row) pairs it connects. Built once per batch and resolution level and
// shared by every layer that convolves there (RulebookCache).
//
// Conventions match torch::conv2d (cross-correlation): offset d = (dy, dx),
// index dy * k + dx, connects input site s * o - p + d to output site o.
// Submanifold (stride 1, p = k / 2): output sites = input sites.
// Strided: output sites = every o that some active input reaches.
#pragma once

#include <torch/types.h>

#include <map>
#include <memory>
#include <mutex>
#include <tuple>

#include "digital_sun_sensor/sparse/site_set.h"

namespace dss::sparse {

struct Rulebook {
  int kernel_size = 1;
  int stride = 1;
  int padding = 0;
  std::shared_ptr<const SiteSet> input;
  std::shared_ptr<const SiteSet> output;
  torch::Tensor in_rows;                   // int32 [pairs], grouped by offset
  torch::Tensor out_rows;                  // int32 [pairs]
  std::vector<std::int64_t> offset_begin;  // [k * k + 1] into the pair arrays
  int identity_offset = -1;                // offset whose pairs are (r, r) for all rows, or -1

  int numOffsets() const { return kernel_size * kernel_size; }
  std::int64_t numPairs() const { return offset_begin.back(); }
};

// Odd k; output sites = input sites.
std::shared_ptr<const Rulebook> submanifoldRulebook(std::shared_ptr<const SiteSet> input, int kernel_size);

// Any k >= 1, stride >= 1, 0 <= padding < k. Output extent (H + 2p - k) / s + 1.
std::shared_ptr<const Rulebook> stridedRulebook(std::shared_ptr<const SiteSet> input, int kernel_size, int stride,
                                                int padding);

// The single offset `offset` of `rulebook` as a 1x1 rulebook on the same output
// sites: e.g. the centre of a 3x3 stride-2 pad-1 rulebook is the 1x1 stride-2
// convolution of a residual shortcut, evaluated where the main path has sites.
std::shared_ptr<const Rulebook> singleOffsetRulebook(const Rulebook& rulebook, int offset);

// Rulebooks of one batch, keyed by input sites and geometry.
class RulebookCache {
 public:
  enum class Kind { kSubmanifold, kStrided, kShortcut };
  std::shared_ptr<const Rulebook> get(const std::shared_ptr<const SiteSet>& input, Kind kind, int kernel_size,
                                      int stride = 1, int padding = 0);

 private:
  using Key = std::tuple<const SiteSet*, int, int, int, int>;
  std::mutex mutex_;
  std::map<Key, std::shared_ptr<const Rulebook>> cache_;
};

}  // namespace dss::sparse
