// Post-hoc calibration of the SSCNN's predicted uncertainty. The variance head
// learns the shape of the error (which images are harder), but its overall
// level converges slowly: the log-variance must travel ~16 units from its
// initial value, further than the learning rate carries it. One factor per
// axis on the predicted sigma, fitted on held-out images so that 68.27 % of
// errors lie within 1 sigma, fixes the level; it is folded into the variance
// head's bias, so the model file stays self-contained. Where the head's shape
// is worse than none (2 and 3 sigma coverage further from the Gaussian's than a
// constant sigma's), the head is replaced by a constant per axis, scaled with
// the image's lit-site count when that covers few- and many-site images alike
// (eval/uncertainty's SiteSigmaLaw). Torch-free header.
#pragma once

#include <cstddef>
#include <optional>

#include "digital_sun_sensor/eval/uncertainty.h"
#include "digital_sun_sensor/train/training_set.h"

namespace dss {

struct Model;

struct SigmaCalibration {
  std::size_t samples = 0;
  double scale_alpha = 1.0, scale_beta = 1.0;  // factors on the head's sigma for 68.27 % coverage
  // A constant sigma per axis replaced the head's (its shape did not follow the error),
  // at reference_sites of site_law when that is active.
  bool constant = false;
  double constant_sigma_alpha_rad = 0.0, constant_sigma_beta_rad = 0.0;
  SiteSigmaLaw site_law;  // the constant's scaling with the lit-site count (inactive: none, or the head's sigma)
  Coverage alpha_before, beta_before, alpha_after, beta_after;  // after: of what the model now predicts
};

// Fits and applies the factors (or the constant) on (at most `max_samples`, evenly spaced)
// samples of `data`, which must be encoded with the model's input spec, and
// records them in the model's metrics. Under a dihedral inference symmetry
// both axes get one factor (or constant), fitted on both axes' errors: the
// averaged variances mix the head's two outputs. Throws std::invalid_argument when
// `data` is empty or its spec differs from the model's. `progress` follows
// the model's predictions on the samples.
SigmaCalibration calibrateSigma(Model& model, const TrainingSet& data, std::size_t max_samples,
                                const SampleProgress& progress = {});

// The same, applied only where the model's sigma holds fewer than
// `min_coverage` of the errors within 1 sigma on either axis (a built unit
// less accurate than its family model: too few images to refit a sound
// sigma, but enough to see one that is far too small); else the model is
// left as it was and nothing is returned.
std::optional<SigmaCalibration> calibrateSigmaWhereTooSmall(Model& model, const TrainingSet& data,
                                                            std::size_t max_samples, double min_coverage);

}  // namespace dss
