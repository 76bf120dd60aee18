// dss report: the credibility report (src/eval/report) of a model beside the
// centroid baseline, on data it generates itself; no ROS master needed.
#include <chrono>
#include <filesystem>
#include <iostream>
#include <optional>

#include "commands.h"
#include "digital_sun_sensor/baseline/calibration.h"
#include "digital_sun_sensor/baseline/centroid_estimator.h"
#include "digital_sun_sensor/estimate/screened_estimator.h"
#include "digital_sun_sensor/eval/report.h"
#include "digital_sun_sensor/model/metadata.h"
#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/model/sscnn_estimator.h"
#include "digital_sun_sensor/sparse/threads.h"

namespace dss::cli {

int runReport(int argc, char** argv) {
  Args args(
      "dss report",
      "Writes a credibility report of an SSCNN model beside the centroid baseline: DIR/index.html, PNG plots and "
      "DIR/summary.json (accuracy over the field of view, uncertainty coverage, robustness sweeps of every noise "
      "and anomaly term, invalid-flag rates, provenance). Generates its own data; prints the summary JSON.",
      {
          {"model", "MODEL", "SSCNN model file", "", true, false},
          {"sensor", "CFG", "sensor config (default: the one the model was made for)", "", false, false},
          {"set", "KEY=VALUE", "override a key of --sensor", "", false, true},
          {"calibration", "CALIB",
           "centroid baseline (default: MODEL's directory/<sensor>.calib.yaml; none: no baseline)", "", false, false},
          {"out", "DIR", "report directory", "", true, false},
          {"seed", "S", "seed of all generated data", "1", false, false},
          {"test-images", "N", "nominal test images", "2000", false, false},
          {"sweep-images", "N", "images per robustness level", "100", false, false},
          {"sweep-sensors", "K", "sensors drawn per robustness level", "4", false, false},
          {"threads", "T", "render threads", "2", false, false},
          {"published-model", "MODEL",
           "model trained on the published protocol, shown beside the published SSCNN (default: MODEL's "
           "directory/<sensor>_published.dssmodel when it exists; none: leave out)",
           "", false, false},
          {"published-calibration", "CALIB",
           "centroid baseline on the published protocol (default: the published model's .calib.yaml; none: leave out)",
           "", false, false},
          {"published-images", "N", "published-protocol test images", "1000", false, false},
          {"published-seed", "S", "grid shuffle of the published-protocol test images", "531", false, false},
          {"published-offset", "K", "first grid position of the published-protocol test images", "30000", false, false},
      });
  if (!args.parse(argc, argv, 2)) return 0;
  sparse::configureThreads(1, 1);
  const std::string model_path = args.get("model");
  const Model model = loadModel(model_path);
  SensorConfig sensor = args.has("sensor") ? loadSensorConfig(args.get("sensor"), args.all("set"))
                                           : parseSensorConfig(model.meta.sensor_yaml, model_path + " (sensor)");
  ScreenedEstimator sscnn(std::make_unique<SscnnEstimator>(model_path, &sensor), ScreenOptions{});

  std::string calibration_path =
      args.has("calibration")
          ? args.get("calibration")
          : (std::filesystem::path(model_path).parent_path() / (sensor.name + ".calib.yaml")).string();
  std::unique_ptr<CentroidEstimator> baseline;
  if (calibration_path != "none" && std::filesystem::exists(calibration_path)) {
    baseline = std::make_unique<CentroidEstimator>(loadCalibration(calibration_path));
  } else if (args.has("calibration") && calibration_path != "none") {
    throw UsageError("dss report: --calibration " + calibration_path + " does not exist");
  } else {
    calibration_path = "none";
  }

  // The published protocol: a model trained on it, and its baseline.
  const std::filesystem::path model_dir = std::filesystem::path(model_path).parent_path();
  std::string published_path = args.has("published-model")
                                   ? args.get("published-model")
                                   : (model_dir / (sensor.name + "_published.dssmodel")).string();
  if (args.has("published-model") && published_path != "none" && !std::filesystem::exists(published_path))
    throw UsageError("dss report: --published-model " + published_path + " does not exist");
  std::optional<PublishedProtocolRun> published;
  std::unique_ptr<SunEstimator> published_sscnn, published_baseline;
  std::string published_calibration = "none";
  if (published_path != "none" && std::filesystem::exists(published_path)) {
    auto protocol_sscnn = std::make_unique<SscnnEstimator>(published_path);
    published.emplace();
    published->sensor = protocol_sscnn->sensor();  // the protocol's, as embedded in the model
    published->sscnn = protocol_sscnn.get();
    published_sscnn = std::move(protocol_sscnn);
    published_calibration = args.has("published-calibration")
                                ? args.get("published-calibration")
                                : std::filesystem::path(published_path).replace_extension(".calib.yaml").string();
    if (published_calibration != "none" && std::filesystem::exists(published_calibration)) {
      published_baseline = std::make_unique<CentroidEstimator>(loadCalibration(published_calibration));
      published->baseline = published_baseline.get();
    } else if (args.has("published-calibration") && published_calibration != "none") {
      throw UsageError("dss report: --published-calibration " + published_calibration + " does not exist");
    } else {
      published_calibration = "none";
    }
  }

  ReportOptions options;
  options.out_dir = args.get("out");
  options.seed = static_cast<std::uint64_t>(args.getInt("seed"));
  options.test_images = static_cast<int>(args.getInt("test-images"));
  options.sweep_images = static_cast<int>(args.getInt("sweep-images"));
  options.sweep_sensors = static_cast<int>(args.getInt("sweep-sensors"));
  options.threads = static_cast<int>(args.getInt("threads"));
  for (int i = 0; i < argc; ++i) options.command += (i ? " " : "") + std::string(argv[i]);
  options.sensor_path = args.has("sensor") ? args.get("sensor") : model_path + " (embedded)";
  options.sscnn_description = model_path + " (" + model.meta.arch.name + ")";
  options.baseline_description = calibration_path;
  options.model_metadata_yaml = metadataToYaml(model.meta);
  options.published_images = static_cast<int>(args.getInt("published-images"));
  options.published_grid_seed = static_cast<std::uint64_t>(args.getInt("published-seed"));
  options.published_grid_offset = static_cast<std::uint64_t>(args.getInt("published-offset"));
  options.published_sscnn_description = published ? published_path : "none";
  options.published_baseline_description = published_calibration;
  try {
    options.validate();
  } catch (const std::invalid_argument& e) {
    throw UsageError(std::string("dss ") + e.what());
  }

  const auto t0 = std::chrono::steady_clock::now();
  std::string last_stage;
  const std::string summary = writeReport(
      sensor, sscnn, baseline.get(), options,
      [&](const std::string& stage, std::size_t done, std::size_t total) {
        if (stage != last_stage) std::cerr << "report: " << stage << "\n";
        if (total > 1 && done > 0) std::cerr << "report: " << stage << " " << done << "/" << total << "\n";
        last_stage = stage;
      },
      published ? &*published : nullptr);
  std::cerr << "report: wrote " << options.out_dir << "/index.html in "
            << std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() << " s\n";
  std::cout << summary << std::endl;
  return 0;
}

}  // namespace dss::cli
