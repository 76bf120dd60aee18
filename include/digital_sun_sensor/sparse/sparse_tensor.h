// A batch of sparse feature maps at one resolution level: feature rows for the
// active sites, and the rulebook cache shared by every tensor of the batch.
#pragma once

#include "digital_sun_sensor/sparse/rulebook.h"

namespace dss::sparse {

struct SparseTensor {
  torch::Tensor features;  // [sites, channels]
  std::shared_ptr<const SiteSet> sites;
  std::shared_ptr<RulebookCache> rulebooks;

  SparseTensor with(torch::Tensor new_features) const { return {std::move(new_features), sites, rulebooks}; }
  std::shared_ptr<const Rulebook> rulebook(RulebookCache::Kind kind, int kernel_size, int stride = 1,
                                           int padding = 0) const {
    return rulebooks->get(sites, kind, kernel_size, stride, padding);
  }
};

}  // namespace dss::sparse
