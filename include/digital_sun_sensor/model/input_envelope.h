// The range of lit-pixel counts (active sites) a model saw in training. An
// image far outside it is unlike anything the model learned from, whatever
// its predicted sigma says: a sigma-free out-of-distribution check (stray
// light lifting the background over the threshold, a spot dimmed or split by
// debris). Torch-free.
#pragma once

#include <vector>

#include "digital_sun_sensor/model/metadata.h"

namespace dss {

struct InputEnvelope {
  int min_sites = 0, max_sites = 0;  // both 0: unknown (models made before it existed)

  bool known() const { return max_sites > 0; }
  bool contains(int sites) const { return !known() || (sites >= min_sites && sites <= max_sites); }
};

// The 0.1 % and 99.9 % quantiles of the training images' site counts,
// widened by 25 % each way. Unknown when `site_counts` is empty.
InputEnvelope measureInputEnvelope(std::vector<int> site_counts);

// The smallest envelope holding both (an unknown one adds nothing).
InputEnvelope covering(const InputEnvelope& a, const InputEnvelope& b);

// Stored in the model's metrics as lit_sites_min / lit_sites_max.
InputEnvelope inputEnvelopeOf(const ModelMetadata& meta);
void recordInputEnvelope(ModelMetadata& meta, const InputEnvelope& envelope);

}  // namespace dss
