// The training loss, shared by the trainer and `dss bench train` so that the
// benchmark times the step that training runs. Includes libtorch: for the few
// files that train, not for widely included headers.
#pragma once

#include "digital_sun_sensor/model/sscnn.h"

namespace dss {

// Squared angle error (every image weighted alike, normalized by the residual
// scale), plus the Gaussian NLL of the detached error for the variance head,
// plus `class_weight` x the sub-FOV cross-entropy (skipped when 0). Images
// whose lattice head resolved another class than the true one (whole
// pitches off) are left out of the angle terms.
// `target`: [B, 2] normalized angles; `classes`: [B] class indices.
torch::Tensor trainingLoss(const SscnnOutput& out, const torch::Tensor& target, const torch::Tensor& classes,
                           double residual_scale, double class_weight);

}  // namespace dss
