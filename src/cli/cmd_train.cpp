// dss train: the training core (src/train) on dataset bags, without a ROS master.
#include <atomic>
#include <csignal>
#include <iostream>
#include <optional>

#include "bag_reading.h"
#include "commands.h"
#include "digital_sun_sensor/common/json.h"
#include "digital_sun_sensor/model/arch.h"
#include "digital_sun_sensor/ros/dataset_source.h"
#include "digital_sun_sensor/train/training_job.h"

namespace dss::cli {
namespace {

std::atomic<bool> g_stop{false};
extern "C" void onStopSignal(int) { g_stop = true; }

}  // namespace

int runTrain(int argc, char** argv) {
  const TrainOptions defaults;
  Args args(
      "dss train",
      "Trains an SSCNN on labelled dataset bags (same core as trainer_node). Progress on stderr; checkpoints every "
      "--checkpoint-minutes and on SIGINT/SIGTERM; --resume continues exactly where a checkpoint stopped. The model "
      "(best validated weights) is written atomically to --out; one JSON line summarises the run.",
      {
          {"data", "BAG", "dataset bag(s) of /sun_sensor/image + /sun_sensor/truth", "", true, true},
          {"out", "MODEL", "model file to write", "", true, false},
          {"sensor", "CFG", "sensor config (default: the one recorded in the first bag)", "", false, false},
          {"set", "KEY=VALUE", "override a key of --sensor", "", false, true},
          {"arch", "A",
           "architecture (" + archPresetList() + "; default: the --init model's, else " + defaultArchName() + ")", "",
           false, false},
          {"centroid-weighting", "W",
           "site weights of the centroid branch: learned (equal at the start), value (the intensity-weighted "
           "centroid at the start) or intensity (the intensity-weighted centroid, nothing learned); default: the "
           "--init model's, else intensity with the geometric head and learned with the others",
           "", false, false},
          {"value-saturation", "S",
           "pixel values v (full scale 1) enter the value and intensity weights as v / (1 + S v) (0: as v; the "
           "brightest pixels are the noisiest); default: the --init model's, else for the geometric head the one of "
           "0, 0.5, 1, 2 whose angle correction, fitted on the validation images, reads them best (0 for the "
           "other heads)",
           "", false, false},
          {"feature-corrections", "ON_OFF",
           "angle corrections from the pooled backbone features (on), or the angles a smooth function of the spot "
           "position alone (off); default: the --init model's, else on",
           "", false, false},
          {"spot-readout", "R",
           "the geometric head's read-out of a whole spot: centroid (its weighted centroid) or symmetry (its point "
           "of symmetry, fitted; less noise on spots with steep flanks); default: the --init model's, else centroid",
           "", false, false},
          {"lattice-phase", "RULE",
           "lattice masks: whole spots read spot by spot (spotwise) or their sites pooled (whole_spots, the shipped "
           "thesis_ma); default: the --init model's, else spotwise",
           "", false, false},
          {"head", "HEAD",
           "which head solves the angles: geometric (through the sensor's geometry, any mask), pattern (the "
           "whole-pattern solve of a mask whose spots merge), classic (the mask-family heads: centroid, lattice, "
           "aperture code) or auto (pattern where most apertures' spots merge, geometric for other masks of several "
           "apertures that are not a full centred lattice); default: the --init model's, else auto",
           "", false, false},
          {"init", "MODEL", "start from this model's weights (fine-tuning; it must suit the sensor)", "", false, false},
          {"resume", "CKPT", "continue from this checkpoint", "", false, false},
          {"checkpoint", "CKPT", "checkpoint file (default: MODEL.ckpt, or the --resume file)", "", false, false},
          {"checkpoint-minutes", "M", "minutes between checkpoints", defaultText(defaults.checkpoint_interval_s / 60),
           false, false},
          {"epochs", "N",
           "epochs of the learning-rate schedule (0: write the model as created, validated, with its sigma and "
           "input envelope fitted; auto: " +
               std::to_string(kGeometricHeadEpochs) + " with the geometric head, " +
               std::to_string(kClassicHeadEpochs) + " with the classic heads, " + std::to_string(kPatternHeadEpochs) +
               " with the pattern head)",
           "auto", false, false},
          {"batch", "B", "images per step", std::to_string(defaults.batch_size), false, false},
          {"lr", "LR", "peak learning rate (AdamW)", defaultText(defaults.learning_rate), false, false},
          {"weight-decay", "W", "AdamW decoupled weight decay", defaultText(defaults.weight_decay), false, false},
          {"patience", "N", "stop after N epochs without validation improvement (0: never)",
           std::to_string(defaults.patience_epochs), false, false},
          {"val-fraction", "F", "fraction of the images held out for validation", "0.1", false, false},
          {"val-max", "N", "validate on at most N held-out images (evenly spaced)",
           std::to_string(defaults.validation_max), false, false},
          {"class-loss-weight", "W", "weight of the sub-FOV cross-entropy in the loss",
           defaultText(defaults.class_loss_weight), false, false},
          {"image-topic", "TOPIC", "image topic in the bags", DatasetTopics{}.image, false, false},
          {"truth-topic", "TOPIC",
           "truth topic in the bags: SunAngles, or a geometry_msgs/Vector3Stamped sun vector in the sensor frame",
           DatasetTopics{}.truth, false, false},
          {"seed", "S", "seed of weights, split, data order and augmentation", std::to_string(defaults.seed), false,
           false},
          {"max-minutes", "M", "stop with a checkpoint after M minutes of training (0: no limit)", "0", false, false},
          {"max-images", "N", "read at most N images (0: all)", "0", false, false},
          {"augment", "KEY=V", "augmentation rate, e.g. noise_probability=0.3 (repeatable; see README)", "", false,
           true},
          {"aten-threads", "N", "ATen (OpenMP) threads", std::to_string(defaults.aten_threads), false, false},
          {"blas-threads", "N", "OpenBLAS threads", std::to_string(defaults.blas_threads), false, false},
      });
  if (!args.parse(argc, argv, 2)) return 0;

  TrainOptions options;
  options.arch = args.get("arch");
  options.init_model = args.get("init");
  options.centroid_weighting = args.get("centroid-weighting");
  if (!args.get("value-saturation").empty()) options.value_saturation = args.getDouble("value-saturation");
  options.feature_corrections = args.get("feature-corrections");
  options.spot_readout = args.get("spot-readout");
  options.lattice_phase = args.get("lattice-phase");
  options.head = args.get("head");
  if (args.get("epochs") != "auto") options.epochs = static_cast<int>(args.getInt("epochs"));
  options.batch_size = static_cast<int>(args.getInt("batch"));
  options.learning_rate = args.getDouble("lr");
  options.weight_decay = args.getDouble("weight-decay");
  options.patience_epochs = static_cast<int>(args.getInt("patience"));
  options.validation_max = static_cast<std::size_t>(args.getInt("val-max"));
  options.class_loss_weight = args.getDouble("class-loss-weight");
  options.seed = static_cast<std::uint64_t>(args.getInt("seed"));
  options.max_minutes = args.getDouble("max-minutes");
  options.checkpoint_interval_s = 60.0 * args.getDouble("checkpoint-minutes");
  options.aten_threads = static_cast<int>(args.getInt("aten-threads"));
  options.blas_threads = static_cast<int>(args.getInt("blas-threads"));
  for (const auto& a : args.all("augment")) setAugmentation(options.augmentation, a);
  options.checkpoint_path = args.has("checkpoint") ? args.get("checkpoint")
                            : args.has("resume")   ? args.get("resume")
                                                   : args.get("out") + ".ckpt";
  TrainingJobSpec job;
  job.output = args.get("out");
  for (const auto& bag : args.all("data")) job.data_description += (job.data_description.empty() ? "" : " ") + bag;
  job.validation_fraction = args.getDouble("val-fraction");
  job.resume_from = args.has("resume") ? args.get("resume") : "";
  job.options = options;
  try {
    job.validate();
  } catch (const std::invalid_argument& e) {
    throw UsageError(std::string("dss train: ") + e.what());
  }

  std::optional<SensorConfig> sensor;
  if (args.has("sensor")) sensor = loadSensorConfig(args.get("sensor"), args.all("set"));
  DatasetTopics topics;
  topics.image = args.get("image-topic");
  topics.truth = args.get("truth-topic");
  const auto max_images = static_cast<std::uint64_t>(args.getInt("max-images"));
  TrainingData data = readLabelledBags("train", args.all("data"), sensor, topics, max_images);
  std::cerr << data.samples.memoryBytes() / (1 << 20) << " MiB in memory\n";

  std::signal(SIGINT, onStopSignal);
  std::signal(SIGTERM, onStopSignal);
  const TrainingJobResult outcome = runTrainingJob(
      data.sensor, data.samples, job, [](const std::string& line) { std::cerr << line << "\n"; },
      [](const TrainProgress& p) { std::cerr << formatProgress(p) << std::endl; }, g_stop);
  std::signal(SIGINT, SIG_DFL);
  std::signal(SIGTERM, SIG_DFL);
  if (!outcome.model_written) std::cerr << "continue with: dss train ... --resume " << options.checkpoint_path << "\n";
  const TrainResult& result = outcome.result;
  const bool complete = outcome.model_written;
  const auto& p = result.last;
  std::cout << "{\"command\": \"train\", \"sensor\": \"" << data.sensor.name << "\", \"arch\": \"" << outcome.arch
            << "\", \"stop\": \"" << toString(result.stop)
            << "\", \"model\": " << (complete ? "\"" + args.get("out") + "\"" : "null") << ", \"checkpoint\": \""
            << options.checkpoint_path << "\", \"epochs_completed\": " << result.epochs_completed
            << ", \"wall_s\": " << result.wall_s << ", \"images_per_s\": " << p.images_per_s
            << ", \"val_alpha_mean_deg\": " << json::number(p.val_alpha_mean_deg)
            << ", \"val_beta_mean_deg\": " << json::number(p.val_beta_mean_deg)
            << ", \"val_alpha_max_deg\": " << json::number(p.val_alpha_max_deg)
            << ", \"val_beta_max_deg\": " << json::number(p.val_beta_max_deg)
            << ", \"val_class_accuracy\": " << p.val_class_accuracy << ", \"val_gross\": " << p.val_gross
            << ", \"best_val_mean_deg\": " << json::number(p.best_val_mean_deg)
            << ", \"best_epoch\": " << p.best_epoch + 1 << "}" << std::endl;
  return complete ? 0 : 3;
}

}  // namespace dss::cli
