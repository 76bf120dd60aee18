#include "digital_sun_sensor/train/training_job.h"

#include <stdexcept>

namespace dss {

void TrainingJobSpec::validate() const {
  if (output.empty()) throw std::invalid_argument("training job: no model file to write");
  if (!(validation_fraction >= 0.0 && validation_fraction < 1.0))
    throw std::invalid_argument("training job: validation fraction must be in [0, 1)");
  options.validate();
}

TrainingJobResult runTrainingJob(const SensorConfig& sensor, const TrainingSet& samples, const TrainingJobSpec& spec,
                                 const std::function<void(const std::string&)>& info,
                                 const std::function<void(const TrainProgress&)>& progress,
                                 const std::atomic<bool>& stop) {
  spec.validate();
  TrainingSet train{samples.spec()}, validation{samples.spec()};
  samples.split(spec.validation_fraction, spec.options.seed, train, validation);
  TrainingJobResult job;
  job.train_images = train.size();
  job.validation_images = validation.size();
  info("sensor " + sensor.name + ": " + std::to_string(train.size()) + " training, " +
       std::to_string(validation.size()) + " validation images; checkpoint " + spec.options.checkpoint_path);
  Trainer trainer(sensor, std::move(train), std::move(validation), spec.options);
  job.arch = trainer.archName();
  if (!spec.resume_from.empty()) {
    trainer.resume(spec.resume_from);
    info("resumed from " + spec.resume_from);
  }
  job.result = trainer.run(progress, stop);
  job.model_written = job.result.stop == TrainStop::finished || job.result.stop == TrainStop::early_stopped;
  if (job.model_written) {
    const std::string finish = trainer.saveModel(spec.output, spec.data_description);
    if (!finish.empty()) info(finish);
    info("wrote " + spec.output + " (" + toString(job.result.stop) + " after " +
         std::to_string(static_cast<long>(job.result.wall_s)) + " s)");
  } else {
    info(std::string("stopped (") + toString(job.result.stop) + "); checkpoint " + spec.options.checkpoint_path);
  }
  return job;
}

}  // namespace dss
