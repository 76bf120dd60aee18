// The trainer's state and steps, shared by the files that implement them
// (private to src/train): schedule.cpp (learning rate, data order),
// training_step.cpp (one optimizer step), epoch_validation.cpp (validation and
// the best weights), checkpoint.cpp (checkpoints and resume), trainer.cpp
// (set-up, the run loop, the model written).
#pragma once

#include <torch/optim/adamw.h>

#include <memory>
#include <string>
#include <vector>

#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/train/trainer.h"

namespace YAML {
class Node;
}

namespace dss {

// The validation figures of `p` as a YAML map (validation_alpha_mean_deg,
// ...): the model file's metrics, and a checkpoint's last validation.
std::string validationYaml(const TrainProgress& p);
// Reads such a map back into `p` (YAML::Exception on a missing key).
void readValidationYaml(const YAML::Node& map, TrainProgress& p);

struct Trainer::Impl {
  SensorConfig sensor;
  TrainingSet train, validation;
  TrainOptions options;
  Model model;
  std::unique_ptr<torch::optim::AdamW> optimizer;
  std::uint64_t data_fingerprint = 0;
  // The value saturation was left to the trainer (a fresh geometric head):
  // chosen on the validation images when the model is written.
  bool choose_value_saturation = false;

  // Position and history: everything a resumed run needs besides weights.
  int epoch = 0;
  std::int64_t step_in_epoch = 0;
  double elapsed_before_s = 0.0;  // wall time of earlier runs
  double best_val_mean_deg = 0.0;
  int best_epoch = -1;
  std::string best_model_bytes;  // serialized best model ("" until validated)
  TrainProgress last;

  Impl(const SensorConfig& s, TrainingSet t, TrainingSet v, TrainOptions o);

  std::int64_t imagesPerStep() const;

  std::int64_t stepsPerEpoch() const;

  double learningRate(std::int64_t global_step) const;

  // The epoch's data order: a seeded permutation, so a resumed run sees the same.
  std::vector<std::size_t> epochOrder(int e) const;

  // One optimizer step on the batch at (epoch, step); returns the loss.
  double step(const std::vector<std::size_t>& order);

  // Fills the val_* fields of `out` from (at most validation_max) validation samples.
  void measure(TrainProgress& out);

  void validate();

  // `elapsed_s`: training wall time up to now, over every run of this job.
  std::string stateYaml(double elapsed_s) const;

  std::string optimizerBytes() const;

  void saveCheckpoint(const std::string& path, double elapsed_s) const;

  void resume(const std::string& path);

  // The current weights with training summary and metrics in the metadata.
  Model withMetadata(const std::string& data_description) const;
};

// Identifies the training data: a resumed run must see exactly the same samples.
std::uint64_t trainingDataFingerprint(const TrainingSet& set);

}  // namespace dss
