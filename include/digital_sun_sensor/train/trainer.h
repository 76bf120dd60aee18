// The training core behind `dss train` and trainer_node: fits an SSCNN to a
// TrainingSet with a seeded, fully reproducible schedule, validates every
// epoch, keeps the best weights (early stopping), and checkpoints so that a
// resumed run continues exactly where it stopped (weights, optimizer state,
// epoch, position in the epoch's data order). Torch-free interface.
#pragma once

#include <atomic>
#include <functional>
#include <memory>
#include <stdexcept>
#include <string>

#include "digital_sun_sensor/model/arch.h"
#include "digital_sun_sensor/sim/sensor_config.h"
#include "digital_sun_sensor/train/training_set.h"

namespace dss {

// A checkpoint that cannot be resumed; the message names the file and why.
class CheckpointError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// `epochs` chosen by the head. The geometric head's weights only refine a solve
// that is right as created: on drawn masks one annealed schedule of 2 epochs
// beat 10 (whose best validation came after the first, still at the peak
// learning rate; docs/results/irregular_masks.md). The classic heads learn
// their angles and need the long schedule of the shipped recipes.
constexpr int kEpochsAuto = -1;
constexpr int kGeometricHeadEpochs = 2;
constexpr int kClassicHeadEpochs = 20;
constexpr int kPatternHeadEpochs = 0;  // the model as created: nothing in its solve trains by gradient

struct TrainOptions {
  std::string arch;  // architecture preset (empty: the init model's, else defaultArchName())
  // Start from this model file's weights (fine-tuning, e.g. on anomalies)
  // instead of fresh ones; it must suit the sensor and, if given, `arch`.
  std::string init_model;
  // Site weights of the centroid branch: "learned", "value" or "intensity" (ArchSpec::
  // centroid_weighting; empty: the init model's, else "intensity" with the geometric head, "learned" with the others).
  std::string centroid_weighting;
  // ArchSpec::value_saturation (>= 0); negative: the init model's, else chosen
  // on the validation images for the geometric head (train/value_saturation_choice), 0 for the others.
  double value_saturation = -1.0;
  // Angle corrections from the pooled features: "on" or "off" (ArchSpec::
  // feature_corrections; empty: the init model's, else "on").
  std::string feature_corrections;
  // The geometric head's read-out of a whole spot: "centroid" (its weighted
  // centroid) or "symmetry" (its point of symmetry; ArchSpec::
  // geometric_symmetric_spots); empty: the init model's, else "centroid".
  std::string spot_readout;
  // Lattice masks: "spotwise" (whole spots read spot by spot) or "whole_spots"
  // (their sites pooled, as the shipped thesis_ma); empty: the init model's,
  // else "spotwise". HeadOptions::lattice_spotwise_phase.
  std::string lattice_phase;
  // Which head solves the angles (HeadOptions::head): "auto", "geometric",
  // "pattern" or "classic"; empty: the init model's, else "auto".
  std::string head;
  int batch_size = 64;
  // The learning-rate schedule spans this many (0: the model as created;
  // kEpochsAuto: the head's, kGeometricHeadEpochs, kClassicHeadEpochs or kPatternHeadEpochs).
  int epochs = kEpochsAuto;
  int patience_epochs = 0;          // stop when validation has not improved for this many (0: never)
  double learning_rate = 5e-4;      // peak, after a linear warm-up (measured: docs/training.md)
  double warmup_fraction = 0.03;    // of all steps
  double final_lr_fraction = 0.01;  // cosine decay ends at this fraction of the peak
  double weight_decay = 0.0;        // AdamW decoupled decay
  double class_loss_weight = 0.1;   // sub-FOV cross-entropy beside the angle NLL
  std::uint64_t seed = 1;           // weights, data order, augmentation
  double max_minutes = 0.0;         // stop (with a checkpoint) after this wall time (0: no limit)
  std::string checkpoint_path;      // empty: no checkpoints
  double checkpoint_interval_s = 300.0;
  double progress_interval_s = 2.0;   // 0: after every step
  std::size_t validation_max = 4000;  // validate on at most this many samples (evenly spaced)
  AugmentationConfig augmentation;
  int aten_threads = 1;
  int blas_threads = 2;

  // Throws std::invalid_argument naming the bad option.
  void validate() const;
};

struct TrainProgress {
  int epoch = 0;  // 0-based
  int epochs = 0;
  std::int64_t step_in_epoch = 0;
  std::int64_t steps_per_epoch = 0;
  double loss = 0.0;  // running mean over the last steps
  double learning_rate = 0.0;
  double images_per_s = 0.0;
  double elapsed_s = 0.0;  // training wall time, including earlier runs of a resumed job
  double eta_s = 0.0;
  bool epoch_end = false;  // validation figures below are fresh
  double val_alpha_mean_deg = 0.0, val_beta_mean_deg = 0.0;
  double val_alpha_max_deg = 0.0, val_beta_max_deg = 0.0;
  double val_class_accuracy = 0.0;
  // Validation images left out of the mean and max: declined (ambiguous
  // aperture) or resolved to a wrong class and off by over 1 deg
  // (validation_error.h).
  std::int64_t val_gross = 0;
  double best_val_mean_deg = 0.0;
  int best_epoch = -1;
};

// The architecture and head options of the fresh model (no init model) that
// training with `options` makes for `sensor`; fills the empty choices of
// `options` (arch, feature corrections, lattice phase, head, centroid
// weighting) with their defaults. test_shipped_models holds every shipped
// model's file to what its recipe's options give here.
struct FreshModelDesign {
  ArchSpec arch;
  HeadOptions head;
  // TrainOptions::value_saturation was not given and the head is geometric:
  // the trainer chooses it when it writes the model (arch holds 0 meanwhile).
  bool choose_value_saturation = false;
};
FreshModelDesign freshModelDesign(const SensorConfig& sensor, TrainOptions& options);

// One human-readable line: epoch, step, loss, validation error, images/s, ETA.
std::string formatProgress(const TrainProgress& progress);

enum class TrainStop { finished, early_stopped, time_limit, interrupted };
const char* toString(TrainStop stop);

struct TrainResult {
  TrainStop stop = TrainStop::finished;
  TrainProgress last;        // figures of the last validation (none when a resumed run had nothing left to do)
  int epochs_completed = 0;  // over all runs of the job
  double wall_s = 0.0;
};

class Trainer {
 public:
  // Validation may be empty (then the last weights are kept, no early stop).
  Trainer(const SensorConfig& sensor, TrainingSet train, TrainingSet validation, TrainOptions options);
  ~Trainer();
  Trainer(const Trainer&) = delete;
  Trainer& operator=(const Trainer&) = delete;

  // Restores weights, optimizer state and position. Throws CheckpointError
  // when the file is unreadable or was made for another sensor, architecture,
  // data set or options.
  void resume(const std::string& checkpoint_path);

  // Trains until the schedule ends, early stopping, the time limit or `stop`
  // becomes true; checkpoints on the way and on every exit. `on_progress` is
  // called every few seconds and at each epoch end.
  TrainResult run(const std::function<void(const TrainProgress&)>& on_progress, const std::atomic<bool>& stop);

  // The best validated (else the latest) weights as a model file (atomic),
  // with training summary and validation metrics in its metadata; σ's level,
  // and where the trainer chooses it the value saturation with its angle
  // correction, fitted on the validation images. Returns a line saying what
  // that choice found ("" without one).
  std::string saveModel(const std::string& path, const std::string& data_description) const;

  // Validation figures of the current weights (the val_* fields), without
  // touching the best-model bookkeeping.
  TrainProgress measureValidation();

  std::int64_t stepsPerEpoch() const;
  // The architecture trained: the requested one, or the --init model's or the default when none was.
  const std::string& archName() const;
  // Every weight as one flat vector (tests compare runs).
  std::vector<float> flatWeights() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace dss
