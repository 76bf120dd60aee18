// dss recalibrate: replays images with reference sun directions (a recorded
// bag) through calibration_node's in-flight recalibration
// (model/unit_recalibration) in stream order, and writes the recalibrated
// unit model: the offline twin of ~recalibration, for recorded flight data
// and for measuring it.
#include <yaml-cpp/yaml.h>

#include <cmath>
#include <iostream>
#include <sstream>

#include "bag_reading.h"
#include "commands.h"
#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/model/unit_recalibration.h"
#include "digital_sun_sensor/ros/dataset_source.h"
#include "digital_sun_sensor/sparse/threads.h"

namespace dss::cli {

int runRecalibrate(int argc, char** argv) {
  const RecalibrationOptions defaults;
  Args args(
      "dss recalibrate",
      "Replays a bag of images with reference sun directions (the truth topic: SunAngles, or a "
      "geometry_msgs/Vector3Stamped in the sensor frame) through the in-flight recalibration of calibration_node, "
      "in stream order: pairs whose reference is far from the model's estimate are refused, the geometry of the "
      "model's geometric head is refitted from a bounded window once the references spread over the field, every "
      "--refit-every pairs. Writes the recalibrated unit model atomically and prints one JSON line.",
      {
          {"model", "MODEL", "geometric-head model of the unit (usually a unit model)", "", true, false},
          {"data", "BAG", "bag(s) of the unit's images with references", "", true, true},
          {"out", "MODEL", "unit model to write (may be --model)", "", true, false},
          {"max-images", "N", "replay at most the first N images (0: all)", "0", false, false},
          {"window", "N", "pairs kept", std::to_string(defaults.window), false, false},
          {"min-pairs", "N", "pairs before the first refit", std::to_string(defaults.min_pairs), false, false},
          {"refit-every", "N", "new pairs between refits", std::to_string(defaults.refit_every), false, false},
          {"min-spread-deg", "D", "spread of the references (std of alpha and of beta) before any refit",
           std::to_string(defaults.min_spread_deg), false, false},
          {"max-disagreement-deg", "D", "references farther than this from the estimate are refused",
           std::to_string(defaults.max_disagreement_deg), false, false},
          {"reference-outliers", "F",
           "robustness test: replace this fraction of the references by directions 2 to 5 deg off (seeded)", "0", false,
           false},
          {"seed", "S", "seed of --reference-outliers", "1", false, false},
          {"image-topic", "TOPIC", "image topic in the bags", DatasetTopics{}.image, false, false},
          {"truth-topic", "TOPIC", "reference topic in the bags", DatasetTopics{}.truth, false, false},
      });
  if (!args.parse(argc, argv, 2)) return 0;
  RecalibrationOptions options;
  auto count = [&](const char* name) {
    const long long v = args.getInt(name);
    if (v < 1) throw UsageError(std::string("dss recalibrate: --") + name + " must be at least 1");
    return static_cast<std::size_t>(v);
  };
  options.window = count("window");
  options.min_pairs = count("min-pairs");
  options.refit_every = count("refit-every");
  options.min_spread_deg = args.getDouble("min-spread-deg");
  options.max_disagreement_deg = args.getDouble("max-disagreement-deg");
  try {
    options.validate();
  } catch (const std::invalid_argument& e) {
    throw UsageError(std::string("dss recalibrate: ") + e.what());
  }
  const double outlier_fraction = args.getDouble("reference-outliers");
  if (!(outlier_fraction >= 0.0 && outlier_fraction <= 1.0))
    throw UsageError("dss recalibrate: --reference-outliers must lie in [0, 1]");
  const long long max_images = args.getInt("max-images");
  if (max_images < 0) throw UsageError("dss recalibrate: --max-images must be >= 0");
  sparse::configureThreads(1, 2);
  Model model = loadModel(args.get("model"));
  if (!model.meta.arch.geometric_head)
    throw UsageError("dss recalibrate: " + args.get("model") + " has no geometric head, so no geometry to refit");
  const SensorConfig sensor = parseSensorConfig(model.meta.sensor_yaml, args.get("model") + " (sensor)");
  DatasetTopics topics;
  topics.image = args.get("image-topic");
  topics.truth = args.get("truth-topic");
  const TrainingData data =
      readLabelledBags("recalibrate", args.all("data"), sensor, topics, static_cast<std::uint64_t>(max_images));

  std::vector<std::array<double, 2>> estimates;
  std::vector<UnitImage> images = readUnitImages(model, data.samples, 0, &estimates);
  Rng rng(static_cast<std::uint64_t>(args.getInt("seed")));
  std::size_t corrupted = 0;
  for (auto& image : images) {
    if (!(rng.uniform() < outlier_fraction)) continue;
    const double size = degToRad(rng.uniform(2.0, 5.0)), direction = rng.uniform(0.0, 2.0 * M_PI);
    image.alpha_rad += size * std::cos(direction);
    image.beta_rad += size * std::sin(direction);
    ++corrupted;
  }
  const MaskGeometry before = model.net->geometry()->maskGeometry();
  UnitRecalibrator recalibrator(options);
  std::size_t failures = 0;
  for (std::size_t i = 0; i < images.size(); ++i) {
    recalibrator.add(images[i], estimates[i][0], estimates[i][1]);
    if (!recalibrator.due()) continue;
    try {
      recalibrator.refit(model);
    } catch (const std::invalid_argument& e) {
      if (failures++ == 0) std::cerr << "refit failed: " << e.what() << "\n";
    }
  }
  if (!recalibrator.last())
    throw std::runtime_error("no refit: " + std::to_string(recalibrator.pairs()) + " pairs, spread " +
                             std::to_string(recalibrator.spreadDeg()) + " deg (needs " +
                             std::to_string(options.min_pairs) + " and " + std::to_string(options.min_spread_deg) +
                             " deg)");
  const UnitCalibrationReport& last = *recalibrator.last();
  YAML::Node record = YAML::Load(last.toYaml());
  record["data"] = "in flight (replayed): " + std::to_string(images.size()) + " reference pairs of " +
                   args.all("data").front() + ", " + std::to_string(recalibrator.refits()) + " refits";
  model.meta.unit_yaml = YAML::Dump(record);
  saveModel(model, args.get("out"));
  std::cerr << "wrote " << args.get("out") << "\n";
  const MaskGeometry after = model.net->geometry()->maskGeometry();
  std::cout << "{\"command\": \"recalibrate\", \"model\": \"" << args.get("out") << "\", \"pairs\": " << images.size()
            << ", \"corrupted_references\": " << corrupted << ", \"refused\": " << recalibrator.refused()
            << ", \"refits\": " << recalibrator.refits() << ", \"failed_refits\": " << failures
            << ", \"window_pairs\": " << recalibrator.pairs() << ", \"spread_deg\": " << recalibrator.spreadDeg()
            << ", \"spots\": " << last.spots << ", \"outlier_spots\": " << last.outliers
            << ", \"spot_rms_um_before\": " << last.spot_rms_um_before
            << ", \"spot_rms_um_after\": " << last.spot_rms_um_after
            << ", \"height_change_um\": " << after.height_um - before.height_um << ", \"offset_change_um\": ["
            << after.offset_x_um - before.offset_x_um << ", " << after.offset_y_um - before.offset_y_um
            << "], \"height_sigma_um\": " << last.standard_errors[0] << "}" << std::endl;
  return 0;
}

}  // namespace dss::cli
