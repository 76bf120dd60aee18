// trainer_node: the training core (src/train) on dataset bags, as a ROS node.
// Parameters from the private namespace (config/trainer.yaml, launch/train.launch);
// progress on ~progress (TrainingProgress) and /diagnostics; checkpoints on
// SIGINT/SIGTERM. Exits when training ends (0), is interrupted (3) or fails (1).
#include <diagnostic_updater/diagnostic_updater.h>
#include <digital_sun_sensor/TrainingProgress.h>
#include <ros/ros.h>

#include <csignal>
#include <cstdio>
#include <fstream>
#include <map>
#include <mutex>
#include <optional>

#include "digital_sun_sensor/ros/dataset_source.h"
#include "digital_sun_sensor/ros/node_params.h"
#include "digital_sun_sensor/train/training_job.h"

namespace dss {
namespace {

std::atomic<bool> g_stop{false};
extern "C" void onStopSignal(int) { g_stop = true; }

bool fileExists(const std::string& path) { return std::ifstream(path).good(); }

TrainOptions optionsFromParams(const ros::NodeHandle& pnh) {
  TrainOptions o;
  o.arch = pnh.param<std::string>("arch", "");
  o.init_model = pnh.param<std::string>("init_model", "");
  o.centroid_weighting = pnh.param<std::string>("centroid_weighting", "");
  o.value_saturation = pnh.param("value_saturation", o.value_saturation);
  o.feature_corrections = pnh.param<std::string>("feature_corrections", "");
  o.spot_readout = pnh.param<std::string>("spot_readout", "");
  o.lattice_phase = pnh.param<std::string>("lattice_phase", "");
  o.head = pnh.param<std::string>("head", "");
  o.batch_size = pnh.param("batch_size", o.batch_size);
  // "auto" (or absent): the head's (kGeometricHeadEpochs, kClassicHeadEpochs, kPatternHeadEpochs).
  XmlRpc::XmlRpcValue epochs;
  if (pnh.getParam("epochs", epochs)) {
    if (epochs.getType() == XmlRpc::XmlRpcValue::TypeInt)
      o.epochs = static_cast<int>(epochs);
    else if (epochs.getType() != XmlRpc::XmlRpcValue::TypeString || static_cast<std::string>(epochs) != "auto")
      throw std::invalid_argument("~epochs must be an integer >= 0 or \"auto\"");
  }
  o.patience_epochs = pnh.param("patience_epochs", o.patience_epochs);
  o.learning_rate = pnh.param("learning_rate", o.learning_rate);
  o.weight_decay = pnh.param("weight_decay", o.weight_decay);
  o.class_loss_weight = pnh.param("class_loss_weight", o.class_loss_weight);
  o.seed = static_cast<std::uint64_t>(pnh.param("seed", static_cast<int>(o.seed)));
  o.max_minutes = pnh.param("max_minutes", o.max_minutes);
  o.checkpoint_interval_s = pnh.param("checkpoint_interval_s", o.checkpoint_interval_s);
  o.validation_max = static_cast<std::size_t>(pnh.param("validation_max", static_cast<int>(o.validation_max)));
  o.aten_threads = pnh.param("aten_threads", o.aten_threads);
  o.blas_threads = pnh.param("blas_threads", o.blas_threads);
  std::map<std::string, double> augmentation;
  if (pnh.hasParam("augmentation") && !pnh.getParam("augmentation", augmentation))
    throw std::runtime_error("~augmentation must be a map of names to numbers");
  for (const auto& [key, value] : augmentation) setAugmentation(o.augmentation, key, value);
  o.validate();
  return o;
}

class TrainerNode {
 public:
  explicit TrainerNode(ros::NodeHandle pnh) : pnh_(pnh) {
    progress_pub_ = pnh_.advertise<digital_sun_sensor::TrainingProgress>("progress", 10, /*latch=*/true);
    updater_.setHardwareID("trainer");
    updater_.add("training", this, &TrainerNode::diagnose);
  }

  int run() {
    try {
      return train();
    } catch (const std::exception& e) {
      ROS_FATAL("trainer_node: %s", e.what());
      setState("failed", e.what());
      publish();
      return 1;
    }
  }

 private:
  int train() {
    const std::vector<std::string> bags = stringListParam(pnh_, "bags");
    if (bags.empty()) throw std::runtime_error("~bags is empty: name one or more dataset bags");
    const std::string output = pnh_.param<std::string>("output", "");
    if (output.empty()) throw std::runtime_error("~output is empty: name the model file to write");
    TrainOptions options = optionsFromParams(pnh_);
    options.checkpoint_path = pnh_.param<std::string>("checkpoint", output + ".ckpt");
    TrainingJobSpec job;
    job.output = output;
    for (const auto& bag : bags) job.data_description += (job.data_description.empty() ? "" : " ") + bag;
    job.validation_fraction = pnh_.param("validation_fraction", 0.1);
    if (pnh_.param("resume", false) && fileExists(options.checkpoint_path)) job.resume_from = options.checkpoint_path;
    job.options = options;
    job.validate();
    std::optional<SensorConfig> sensor;
    const std::string sensor_name = pnh_.param<std::string>("sensor_config", "");
    if (!sensor_name.empty()) sensor = loadSensorConfig(resolveSensorConfigPath(sensor_name));
    DatasetTopics topics;
    topics.image = pnh_.param("image_topic", topics.image);
    topics.truth = pnh_.param("truth_topic", topics.truth);

    setState("reading", "reading " + std::to_string(bags.size()) + " bag(s)");
    publish();
    int last_decile = -1;
    TrainingData data = loadTrainingData(bags, sensor, topics, static_cast<std::uint64_t>(pnh_.param("max_images", 0)),
                                         [&](std::uint64_t done, std::uint64_t total) {
                                           const int decile = total ? static_cast<int>(10 * done / total) : 0;
                                           if (decile != last_decile)
                                             ROS_INFO("reading bags: %llu/%llu images", (unsigned long long)done,
                                                      (unsigned long long)total);
                                           last_decile = decile;
                                           updater_.update();
                                         });
    ROS_INFO("read %s", describe(data).c_str());

    msg_.checkpoint = options.checkpoint_path;
    setState("training", "training");
    const TrainingJobResult outcome = runTrainingJob(
        data.sensor, data.samples, job, [](const std::string& line) { ROS_INFO("%s", line.c_str()); },
        [&](const TrainProgress& p) {
          ROS_INFO("%s", formatProgress(p).c_str());
          fill(p);
          publish();
        },
        g_stop);
    if (outcome.model_written) {
      msg_.model = output;
    } else {
      ROS_WARN("stopped (%s); relaunch with resume:=true to continue", toString(outcome.result.stop));
    }
    fill(outcome.result.last);
    setState(toString(outcome.result.stop), outcome.model_written ? "model written" : "checkpointed");
    publish();
    return outcome.model_written ? 0 : 3;
  }

  void fill(const TrainProgress& p) {
    std::lock_guard<std::mutex> lock(mutex_);
    msg_.epoch = p.epoch + 1;
    msg_.epochs = p.epochs;
    msg_.step = p.step_in_epoch;
    msg_.steps_per_epoch = p.steps_per_epoch;
    msg_.loss = p.loss;
    msg_.learning_rate = p.learning_rate;
    msg_.images_per_s = p.images_per_s;
    msg_.elapsed_s = p.elapsed_s;
    msg_.eta_s = p.eta_s;
    msg_.epoch_end = p.epoch_end;
    msg_.val_alpha_mean_deg = p.val_alpha_mean_deg;
    msg_.val_beta_mean_deg = p.val_beta_mean_deg;
    msg_.val_alpha_max_deg = p.val_alpha_max_deg;
    msg_.val_beta_max_deg = p.val_beta_max_deg;
    msg_.val_class_accuracy = p.val_class_accuracy;
    msg_.val_gross = p.val_gross;
    msg_.best_val_mean_deg = p.best_val_mean_deg;
    msg_.best_epoch = p.best_epoch + 1;
  }

  void setState(const std::string& state, const std::string& detail) {
    std::lock_guard<std::mutex> lock(mutex_);
    msg_.state = state;
    msg_.detail = detail;
  }

  void publish() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      msg_.header.stamp = ros::Time::now();
      progress_pub_.publish(msg_);
    }
    updater_.update();
  }

  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat) {
    std::lock_guard<std::mutex> lock(mutex_);
    using diagnostic_msgs::DiagnosticStatus;
    const auto level = msg_.state == "failed"        ? DiagnosticStatus::ERROR
                       : msg_.state == "interrupted" ? DiagnosticStatus::WARN
                                                     : DiagnosticStatus::OK;
    stat.summary(level, msg_.state + ": " + msg_.detail);
    stat.add("epoch", std::to_string(msg_.epoch) + "/" + std::to_string(msg_.epochs));
    stat.add("step", std::to_string(msg_.step) + "/" + std::to_string(msg_.steps_per_epoch));
    stat.add("loss", msg_.loss);
    stat.add("images_per_s", msg_.images_per_s);
    stat.add("eta_s", msg_.eta_s);
    stat.add("val_alpha_mean_deg", msg_.val_alpha_mean_deg);
    stat.add("val_beta_mean_deg", msg_.val_beta_mean_deg);
    stat.add("val_class_accuracy", msg_.val_class_accuracy);
    stat.add("val_gross", msg_.val_gross);
    stat.add("checkpoint", msg_.checkpoint);
  }

  ros::NodeHandle pnh_;
  ros::Publisher progress_pub_;
  diagnostic_updater::Updater updater_;
  std::mutex mutex_;
  digital_sun_sensor::TrainingProgress msg_;
};

}  // namespace
}  // namespace dss

int main(int argc, char** argv) {
  // Our own handlers: SIGINT/SIGTERM end the current step and checkpoint.
  ros::init(argc, argv, "trainer", ros::init_options::NoSigintHandler);
  std::signal(SIGINT, dss::onStopSignal);
  std::signal(SIGTERM, dss::onStopSignal);
  ros::NodeHandle pnh("~");
  ros::AsyncSpinner spinner(1);
  spinner.start();
  dss::TrainerNode node(pnh);
  const int code = node.run();
  ros::WallDuration(1.0).sleep();  // the last (latched) message reaches late subscribers
  ros::shutdown();
  return code;
}
