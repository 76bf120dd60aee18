// dss subcommands. Each returns the process exit code.
#pragma once

#include <string>
#include <vector>

#include "cli_args.h"
#include "digital_sun_sensor/sim/sensor_config.h"

namespace dss::cli {

int runGenerate(int argc, char** argv);
int runBench(int argc, char** argv);
int runRender(int argc, char** argv);
int runMask(int argc, char** argv);
int runCalibrate(int argc, char** argv);
int runEval(int argc, char** argv);
int runTrain(int argc, char** argv);
int runCalibrateSigma(int argc, char** argv);
int runCalibrateHeight(int argc, char** argv);
int runCalibrateUnit(int argc, char** argv);
int runRecalibrate(int argc, char** argv);
int runReport(int argc, char** argv);
// dss bench infer | train (cmd_bench_nn.cpp: the only CLI file that includes libtorch).
int runBenchInfer(int argc, char** argv);
int runBenchTrain(int argc, char** argv);

// Options shared by every command that loads a sensor config.
std::vector<OptionSpec> sensorOptions();
// Config from --sensor, --set and --anomalies.
SensorConfig loadSensorFromArgs(const Args& args);
// "--anomalies" spec -> config overrides. SPEC: none | mix | comma list of
// stray_light=P, ghost=P, debris=P (probabilities), hot_pixels=N (count),
// as_built=S (scale of the as-built sigmas below, 1 = nominal tolerances).
std::vector<std::string> anomalyOverrides(const std::string& spec);

}  // namespace dss::cli
