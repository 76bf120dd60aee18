// The geometric head's value saturation S (pixel values v weigh v / (1 + S v)
// in its spots' centroids), chosen per sensor on held-out images. Which S
// reads a sensor's spots with the least noise depends on the spots (their
// size, the threshold, the readout): trained with S = 1, drawn mask F went
// from 1.54 to 1.34 x the readout bound, while on mask G S = 0 read about 5 %
// better (docs/sscnn.md#site-weights-and-value-saturation). No weight depends on S, so each candidate
// is scored on the same network: its held-out angle correction refitted
// (train/bias_calibration), the cross-validated RMS compared. Torch-free header.
#pragma once

#include <cstddef>
#include <vector>

#include "digital_sun_sensor/train/bias_calibration.h"
#include "digital_sun_sensor/train/training_set.h"

namespace dss {

struct Model;

// The candidates dss train tries, the first (no saturation) the default.
const std::vector<double>& valueSaturationCandidates();

struct ValueSaturationChoice {
  std::vector<double> candidates;
  // Per candidate: the cross-validated RMS error (deg, both axes) after its angle correction.
  std::vector<double> cross_validated_rms_deg;
  double chosen = 0.0;
  BiasCalibration correction;  // the chosen candidate's
};

// Sets the model's value saturation to each candidate in turn and refits its
// angle correction (degree at most `max_degree`, on at most `max_samples` of
// `data`); keeps the candidate of least cross-validated RMS, a later one only
// where it lowers the best so far by more than 1 % (noise in the choice), with
// its correction, and records the scores in the model's metrics. Throws
// std::invalid_argument for a model without the geometric head, no or
// negative candidates, or what calibrateBias refuses.
ValueSaturationChoice chooseValueSaturation(Model& model, const TrainingSet& data, std::size_t max_samples,
                                            int max_degree,
                                            const std::vector<double>& candidates = valueSaturationCandidates());

}  // namespace dss
