// dss: the digital_sun_sensor command line (no ROS master needed).
#include <iostream>
#include <string>

#include "commands.h"

namespace {

const char* kUsage =
    "usage: dss <command> [options]     (dss <command> --help for its options)\n"
    "\n"
    "commands:\n"
    "  generate   render a dataset (images + ground truth) into a rosbag\n"
    "  render     render one image for a sun direction into a PNG\n"
    "  mask       draw a seeded irregular mask within a sensor config (a config for tests and experiments)\n"
    "  calibrate  fit the conventional baseline (centroid + calibration model) to a labelled bag\n"
    "  train      train an SSCNN model on labelled bags (checkpoints, --resume)\n"
    "  calibrate-sigma  refit the level of a model's predicted sigma on held-out labelled images\n"
    "  calibrate-height fit how a family model's angle correction changes with the mask height\n"
    "  calibrate-unit   fit a geometric-head model's geometry to labelled images of one built unit\n"
    "  recalibrate      replay images with reference sun directions through the in-flight recalibration\n"
    "  eval       evaluate an estimator (sscnn:MODEL | centroid:CALIB) on a labelled bag: one JSON line\n"
    "  report     credibility report of a model beside the baseline: HTML, PNG plots, summary.json\n"
    "  bench      benchmarks printing one JSON line (bench sim|infer|train)\n";

}  // namespace

int main(int argc, char** argv) {
  const std::string command = argc > 1 ? argv[1] : "";
  try {
    if (command == "generate") return dss::cli::runGenerate(argc, argv);
    if (command == "bench") return dss::cli::runBench(argc, argv);
    if (command == "render") return dss::cli::runRender(argc, argv);
    if (command == "mask") return dss::cli::runMask(argc, argv);
    if (command == "calibrate") return dss::cli::runCalibrate(argc, argv);
    if (command == "train") return dss::cli::runTrain(argc, argv);
    if (command == "calibrate-sigma") return dss::cli::runCalibrateSigma(argc, argv);
    if (command == "calibrate-height") return dss::cli::runCalibrateHeight(argc, argv);
    if (command == "calibrate-unit") return dss::cli::runCalibrateUnit(argc, argv);
    if (command == "recalibrate") return dss::cli::runRecalibrate(argc, argv);
    if (command == "eval") return dss::cli::runEval(argc, argv);
    if (command == "report") return dss::cli::runReport(argc, argv);
    if (command == "--help" || command == "-h" || command == "help") {
      std::cout << kUsage;
      return 0;
    }
    std::cerr << (command.empty() ? "" : "dss: unknown command '" + command + "'\n") << kUsage;
    return 2;
  } catch (const dss::cli::UsageError& e) {
    std::cerr << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "dss " << command << ": error: " << e.what() << "\n";
    return 1;
  }
}
