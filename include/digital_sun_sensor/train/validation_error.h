// The trainer's validation figures, from a model's predictions on held-out
// samples: what the progress line shows and what picks the best epoch.
#pragma once

#include <cstddef>
#include <vector>

#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/train/training_set.h"

namespace dss {

// A validation image resolved to a wrong sub-FOV class and off by more than
// this on an axis is a gross failure (a wrong aperture: whole lattice pitches,
// tens of degrees on wide_ma), not an inaccuracy; a handful of them would
// otherwise swamp the mean (0.065 deg from 4 of 2800 stray-lit wide_ma images,
// against about 0.0015 deg for the rest) and hide each epoch's progress.
constexpr double kGrossValidationErrorDeg = 1.0;

struct ValidationError {
  // Over the images neither declined nor grossly failed, per axis, degrees
  // (infinity when none is left).
  double alpha_mean_deg = 0.0, beta_mean_deg = 0.0;
  double alpha_max_deg = 0.0, beta_max_deg = 0.0;
  // Over all images.
  double class_accuracy = 0.0;
  std::size_t images = 0;
  // Left out of the mean and max: declined as the estimator would (aperture
  // code margin below kMinApertureCodeMargin, a lone spot of an unknown
  // aperture), or resolved to a wrong class
  // and off by more than kGrossValidationErrorDeg.
  std::size_t gross = 0;
};

// `samples[k]` is the truth of `predictions[k]`; throws std::invalid_argument
// when the sizes differ.
ValidationError summarizeValidation(const std::vector<const SparseSample*>& samples,
                                    const std::vector<Prediction>& predictions);

}  // namespace dss
