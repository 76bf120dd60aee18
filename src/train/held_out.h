// Predictions of a model on labelled held-out samples, shared by the post-hoc
// calibrations (sigma_calibration, bias_calibration). Internal to src/train.
#pragma once

#include <string>
#include <vector>

#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/train/training_set.h"

namespace dss {

struct HeldOutPrediction {
  const SparseSample* sample;
  Prediction prediction;
};

// The model's predictions on at most `max_samples` evenly spaced samples of
// `data`, leaving out those it answered "no sun", reporting (done, total)
// to `progress` as it goes. Throws std::invalid_argument, prefixed with
// `what`, when `data` is empty or was not encoded with the model's input spec.
std::vector<HeldOutPrediction> predictHeldOut(const Model& model, const TrainingSet& data, std::size_t max_samples,
                                              const std::string& what, const SampleProgress& progress = {});

}  // namespace dss
