// One training job, the flow both front ends run (dss train, trainer_node):
// split the samples, train (or resume a checkpoint), write the model when the
// schedule completes, report what happened. ROS-free and torch-free; the
// front ends read the bags (ros/dataset_source) and present the progress.
#pragma once

#include <atomic>
#include <functional>
#include <string>

#include "digital_sun_sensor/sim/sensor_config.h"
#include "digital_sun_sensor/train/trainer.h"
#include "digital_sun_sensor/train/training_set.h"

namespace dss {

struct TrainingJobSpec {
  std::string output;                // model file, written atomically when training completes
  std::string data_description;      // recorded in the model's training summary (the bags)
  double validation_fraction = 0.1;  // held out by options.seed
  std::string resume_from;           // checkpoint to continue ("": fresh weights)
  TrainOptions options;              // options.checkpoint_path: where checkpoints go

  // Throws std::invalid_argument naming the bad field.
  void validate() const;
};

struct TrainingJobResult {
  TrainResult result;
  bool model_written = false;  // finished or stopped early (else: checkpointed)
  std::string arch;            // the architecture trained
  std::size_t train_images = 0, validation_images = 0;
};

// `info` gets one line per event (split, resume, model written, checkpoint
// kept), `progress` the trainer's progress; `stop` ends training with a
// checkpoint. Throws for bad options, data or checkpoints, naming the problem.
TrainingJobResult runTrainingJob(const SensorConfig& sensor, const TrainingSet& samples, const TrainingJobSpec& spec,
                                 const std::function<void(const std::string&)>& info,
                                 const std::function<void(const TrainProgress&)>& progress,
                                 const std::atomic<bool>& stop);

}  // namespace dss
