// Post-hoc calibration of the SSCNN's predicted uncertainty. The variance head
// learns the shape of the error (which images are harder), but its overall
// level converges slowly: the log-variance must travel ~16 units from its
// initial value, further than the learning rate carries it. One factor per
// axis on the predicted sigma, fitted on held-out images so that 68.27 % of
// errors lie within 1 sigma, fixes the level; it is folded into the variance
// head's bias, so the model file stays self-contained. Torch-free header.
#pragma once

#include <cstddef>

#include "digital_sun_sensor/eval/uncertainty.h"
#include "digital_sun_sensor/train/training_set.h"

namespace dss {

struct Model;

struct SigmaCalibration {
  std::size_t samples = 0;
  double scale_alpha = 1.0, scale_beta = 1.0;  // factors applied to the predicted sigma
  Coverage alpha_before, beta_before, alpha_after, beta_after;
};

// Fits and applies the factors on (at most `max_samples`, evenly spaced)
// samples of `data`, which must be encoded with the model's input spec, and
// records them in the model's metrics. Throws std::invalid_argument when
// `data` is empty or its spec differs from the model's.
SigmaCalibration calibrateSigma(Model& model, const TrainingSet& data, std::size_t max_samples);

}  // namespace dss
