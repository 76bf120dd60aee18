#include "commands.h"

#include "digital_sun_sensor/sim/dataset_generator.h"
#include "digital_sun_sensor/sim/spot_cache.h"

#include <chrono>
#include <iostream>
#include <sstream>
#include <thread>

namespace dss::cli {
namespace {

std::string describe(const SensorConfig& c) {
  std::ostringstream o;
  o << c.detector.width_px << "x" << c.detector.height_px << " " << (c.noise.bit_depth <= 8 ? "mono8" : "mono16")
    << ", " << c.mask.apertures.size() << " aperture(s), "
    << (c.optics.mode == OpticsMode::kFresnel ? "angular-spectrum diffraction" : "far-field") << " at "
    << c.optics.wavelengths_um.size() << " wavelengths" << (c.optics.sun.enabled ? ", limb-darkened sun disk" : "")
    << (c.optics.vignetting ? ", vignetting" : "") << (c.cover_glass.enabled ? ", cover glass" : "")
    << ", pixel integration, shot+read noise" << (c.noise.dark_current_e_per_s > 0 ? "+dark current" : "")
    << (c.noise.dsnu_fraction > 0 ? "+DSNU" : "") << (c.noise.prnu_fraction > 0 ? "+PRNU" : "")
    << (c.threshold.enabled ? ", threshold" : "");
  return o.str();
}

int benchSim(int argc, char** argv) {
  auto specs = sensorOptions();
  const std::string threads = std::to_string(std::max(1u, std::thread::hardware_concurrency()));
  specs.insert(specs.end(), {
                                {"count", "N", "images to render after warm-up", "1000", false, false},
                                {"seed", "S", "seed", "1", false, false},
                                {"threads", "T", "render threads", threads, false, false},
                            });
  Args args("dss bench sim", "Measures simulator throughput (random attitudes over the FOV); prints one JSON line.",
            specs);
  if (!args.parse(argc, argv, 3)) return 0;
  const SensorConfig config = loadSensorFromArgs(args);
  DatasetSpec spec;
  spec.seed = static_cast<std::uint64_t>(args.getInt("seed"));
  spec.threads = static_cast<int>(args.getInt("threads"));
  const auto count = static_cast<std::uint64_t>(args.getInt("count"));

  // Warm-up: the first pass over the FOV fills the diffraction cache (a
  // one-off per sensor); then the measured pass renders new attitudes.
  using Clock = std::chrono::steady_clock;
  spec.count = count;
  DatasetGenerator generator(config, spec);
  auto t0 = Clock::now();
  generator.run([](const DatasetItem&) {});
  const double warm_s = std::chrono::duration<double>(Clock::now() - t0).count();
  generator.setOffset(count);  // new attitudes and noise, warm cache
  std::uint64_t nonzero = 0;
  t0 = Clock::now();
  generator.run([&](const DatasetItem& item) { nonzero += static_cast<std::uint64_t>(cv::countNonZero(item.image)); });
  const double run_s = std::chrono::duration<double>(Clock::now() - t0).count();
  std::cout << "{\"bench\":\"sim\",\"sensor\":\"" << config.name << "\",\"images\":" << count
            << ",\"threads\":" << spec.threads << ",\"images_per_s\":" << count / run_s
            << ",\"ms_per_image_per_thread\":" << 1000.0 * run_s * spec.threads / count
            << ",\"warmup_s\":" << warm_s << ",\"psf_nodes\":" << generator.renderer(0).spotCache().nodesHeld()
            << ",\"mean_nonzero_pixels\":" << static_cast<double>(nonzero) / count << ",\"rendered\":\""
            << describe(config) << "\"}" << std::endl;
  return 0;
}

}  // namespace

int runBench(int argc, char** argv) {
  const std::string what = argc > 2 ? argv[2] : "";
  if (what == "sim") return benchSim(argc, argv);
  if (what == "infer") return runBenchInfer(argc, argv);
  if (what == "train") return runBenchTrain(argc, argv);
  if (what == "--help" || what == "-h" || what.empty()) {
    std::cout << "usage: dss bench sim|infer|train [options]   (dss bench infer --help)\n"
                 "  sim    simulator throughput\n"
                 "  infer  SSCNN single-image inference, sparse vs dense\n"
                 "  train  SSCNN training throughput\n";
    return what.empty() ? 2 : 0;
  }
  throw UsageError("dss bench: unknown benchmark '" + what + "' (available: sim, infer, train)");
}

}  // namespace dss::cli
