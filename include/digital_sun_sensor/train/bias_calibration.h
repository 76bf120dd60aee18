// Post-hoc fit of a model's smooth angle bias (model/angle_correction) on
// labelled held-out images. The degree is chosen by two-fold cross-validation
// (even / odd samples), so the correction is only as rich as held-out images
// confirm, and none when none helps. Images whose error is far beyond the
// typical (whole-pitch misresolutions and the like) are left out of the fit: a
// smooth correction must not chase them. Torch-free header.
#pragma once

#include <cstddef>
#include <optional>
#include <vector>

#include "digital_sun_sensor/model/spot_bias.h"
#include "digital_sun_sensor/train/training_set.h"

namespace dss {

struct Model;

struct BiasCalibration {
  std::size_t samples = 0;   // fitted (estimates within the outlier bound)
  std::size_t outliers = 0;  // left out
  int degree = -1;           // chosen (AngleCorrection::kNone: none)
  // Held-out RMS error (both axes) per candidate degree, from none (index 0)
  // up to the maximum, or the largest the samples support (3 per term and fold).
  std::vector<double> cross_validated_rms_deg;
  double rms_alpha_before_deg = 0.0, rms_beta_before_deg = 0.0;  // on the fitted samples
  double rms_alpha_after_deg = 0.0, rms_beta_after_deg = 0.0;
};

// Replaces the model's angle correction with one of degree at most
// `max_degree` (AngleCorrection::kNone..kMaxDegree) fitted on at most
// `max_samples` evenly spaced samples of `data` (encoded with the model's input
// spec) and records it in the model's metrics. With `add_to_model_correction`
// the model's correction stays and what it leaves is fitted and added to it
// (a unit's refit on a few images on top of its family's wide-field
// correction; `degree` is then the added part's). Throws
// std::invalid_argument for a bad degree, empty data or another input spec.
// `progress` follows the model's predictions on the samples.
BiasCalibration calibrateBias(Model& model, const TrainingSet& data, std::size_t max_samples, int max_degree,
                              bool add_to_model_correction = false, const SampleProgress& progress = {});

struct HeightCalibration {
  BiasCalibration correction;
  std::optional<SpotBiasFit> spot_bias;  // the spot bias's change, where fitted
};

// Geometric head: fits how the model's angle correction changes with the
// mask height (ModelMetadata::height_corrections) on images of the design
// with its mask moved by `height_change_um` (a sensor config with that
// height), the model's geometry moved alike while it fits what the
// correction leaves (degree at most `max_degree`, cross-validated); replaces
// an entry of the same height change, and adds none where no degree helps.
// With a spot bias in the model and `spot_bias_degree` >= 0, then fits the
// bias's change at that height on the same images (fitSpotBias, relative to
// the design's bias, degree at most `spot_bias_degree`) and records it in
// the bias (SpotBias::by_height, replacing one of the same height change;
// kNone: the bias's change at that height is removed, as the correction's
// is refitted against the design's bias). The model must hold its design's
// geometry (a family model). Throws std::invalid_argument naming what is wrong.
HeightCalibration calibrateHeightCorrection(Model& model, const TrainingSet& data, double height_change_um,
                                            std::size_t max_samples, int max_degree,
                                            int spot_bias_degree = AngleCorrection::kNone);

}  // namespace dss
