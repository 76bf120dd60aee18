#include <yaml-cpp/yaml.h>

#include <filesystem>
#include <iostream>
#include <set>
#include <sstream>
#include <thread>

#include "commands.h"
#include "digital_sun_sensor/ros/bag_io.h"
#include "digital_sun_sensor/sim/dataset_generator.h"
#include "digital_sun_sensor/sim/spot_cache.h"
#include "progress.h"

namespace dss::cli {

std::vector<OptionSpec> sensorOptions() {
  return {
      {"sensor", "CFG", "sensor config YAML (config/sensors/*.yaml)", "", true, false},
      {"set", "KEY=VALUE", "override a config key, e.g. optics.mode=far_field", "", false, true},
      {"anomalies", "SPEC", "none | mix | stray_light=P,ghost=P,debris=P,hot_pixels=N,as_built=S", "none", false,
       false},
  };
}

std::vector<std::string> anomalyOverrides(const std::string& spec) {
  std::vector<std::string> out;
  if (spec.empty() || spec == "none") return out;
  std::string expanded = spec;
  if (spec == "mix") expanded = "stray_light=0.3,ghost=0.3,debris=0.3,hot_pixels=30,as_built=1";
  std::stringstream ss(expanded);
  for (std::string item; std::getline(ss, item, ',');) {
    const auto eq = item.find('=');
    if (eq == std::string::npos) throw UsageError("--anomalies: '" + item + "' is not NAME=VALUE");
    const std::string name = item.substr(0, eq), value = item.substr(eq + 1);
    if (name == "stray_light" || name == "ghost" || name == "debris") {
      out.push_back("anomalies." + name + ".probability=" + value);
    } else if (name == "hot_pixels") {
      out.push_back("anomalies.hot_pixels.count=" + value);
    } else if (name == "as_built") {
      const AsBuiltConfig ab = asBuiltTolerances(std::stod(value));
      out.push_back("as_built.height_sigma_um=" + std::to_string(ab.height_sigma_um));
      out.push_back("as_built.offset_sigma_um=" + std::to_string(ab.offset_sigma_um));
      out.push_back("as_built.rotation_sigma_deg=" + std::to_string(ab.rotation_sigma_deg));
      out.push_back("as_built.tilt_sigma_deg=" + std::to_string(ab.tilt_sigma_deg));
      out.push_back("as_built.aperture_position_sigma_um=" + std::to_string(ab.aperture_position_sigma_um));
      out.push_back("as_built.aperture_diameter_sigma_um=" + std::to_string(ab.aperture_diameter_sigma_um));
    } else {
      throw UsageError("--anomalies: unknown anomaly '" + name +
                       "' (expected stray_light, ghost, debris, hot_pixels or as_built)");
    }
  }
  return out;
}

SensorConfig loadSensorFromArgs(const Args& args) {
  std::vector<std::string> overrides = anomalyOverrides(args.get("anomalies"));
  for (const auto& s : args.all("set")) overrides.push_back(s);
  return loadSensorConfig(args.get("sensor"), overrides);
}

int runGenerate(int argc, char** argv) {
  auto specs = sensorOptions();
  const std::string threads = std::to_string(std::max(1u, std::thread::hardware_concurrency()));
  specs.insert(
      specs.end(),
      {
          {"count", "N", "number of images", "", true, false},
          {"seed", "S", "dataset seed (attitudes, noise, sensor draws)", "", true, false},
          {"sampling", "MODE",
           "random (uniform over the FOV) | edge (uniform over its outer band) | grid "
           "(published protocol) | spread (a lab plan: the first N cover the FOV evenly for any N)",
           "random", false, false},
          {"edge-band-deg", "DEG", "edge sampling: width of the band inside the FOV's border",
           defaultText(DatasetSpec{}.edge_band_deg), false, false},
          {"offset", "K", "first sample index (grid: position in the shuffled grid)", "0", false, false},
          {"instances", "K", "sensors drawn from the config (as-built errors, debris, FPN)", "1", false, false},
          {"rate", "HZ", "stamp spacing of the messages in the bag", "10", false, false},
          {"threads", "T", "render threads", threads, false, false},
          {"diffraction-cache-mb", "MB",
           "memory cap of the diffraction cache (0: 40 % of the machine's); past it the least recently used "
           "spots are dropped and computed again (the same bag, more slowly)",
           "0", false, false},
          {"out", "BAG", "output rosbag", "", true, false},
      });
  Args args("dss generate", "Renders a dataset into a rosbag of /sun_sensor/image + /sun_sensor/truth.", specs);
  if (!args.parse(argc, argv, 2)) return 0;
  const SensorConfig config = loadSensorFromArgs(args);
  DatasetSpec spec;
  spec.count = static_cast<std::uint64_t>(args.getInt("count"));
  spec.seed = static_cast<std::uint64_t>(args.getInt("seed"));
  spec.sampling = parseSamplingMode(args.get("sampling"));
  spec.edge_band_deg = args.getDouble("edge-band-deg");
  spec.offset = static_cast<std::uint64_t>(args.getInt("offset"));
  spec.instances = static_cast<int>(args.getInt("instances"));
  spec.threads = static_cast<int>(args.getInt("threads"));
  if (args.getInt("count") <= 0) throw UsageError("dss generate: --count must be > 0");
  if (spec.instances < 1) throw UsageError("dss generate: --instances must be >= 1");
  const long long cache_mb = args.getInt("diffraction-cache-mb");
  if (cache_mb < 0) throw UsageError("dss generate: --diffraction-cache-mb must be >= 0");
  if (cache_mb > 0) SpotCache::setMemoryLimitBytes(static_cast<std::size_t>(cache_mb) << 20);

  YAML::Emitter info;
  info << YAML::BeginMap << YAML::Key << "generator" << YAML::Value << "digital_sun_sensor dss generate 0.1.0";
  info << YAML::Key << "count" << YAML::Value << spec.count << YAML::Key << "seed" << YAML::Value << spec.seed;
  info << YAML::Key << "sampling" << YAML::Value << toString(spec.sampling) << YAML::Key << "offset" << YAML::Value
       << spec.offset;
  if (spec.sampling == SamplingMode::kEdge) info << YAML::Key << "edge_band_deg" << YAML::Value << spec.edge_band_deg;
  info << YAML::Key << "instances" << YAML::Value << spec.instances;
  info << YAML::Key << "anomalies" << YAML::Value << args.get("anomalies");
  info << YAML::Key << "sensor_file" << YAML::Value << args.get("sensor");
  info << YAML::Key << "overrides" << YAML::Value << YAML::Flow << args.all("set");
  info << YAML::Key << "sensor" << YAML::Value << YAML::Load(toYaml(config)) << YAML::EndMap;

  DatasetGenerator generator(config, spec);
  if (std::filesystem::exists(args.get("out") + ".partial"))
    std::cerr << "dss generate: " << args.get("out")
              << ".partial is left from an interrupted run: starting over (the seeded bag comes out the same)\n";
  DatasetBagWriter writer(args.get("out"), config, info.c_str(), args.getDouble("rate"));
  Progress progress("generate", spec.count);
  generator.run([&](const DatasetItem& item) { writer.write(item); },
                [&](std::uint64_t done, std::uint64_t total) {
                  (void)total;
                  progress.update(done);
                });
  progress.finish();
  writer.commit();
  std::cerr << "wrote " << spec.count << " images of " << config.name << " to " << args.get("out") << "\n";
  std::set<const SpotCache*> caches;  // instances of one mask height share theirs
  for (int k = 0; k < spec.instances; ++k) caches.insert(&generator.renderer(k).spotCache());
  std::size_t dropped = 0;
  for (const SpotCache* cache : caches) dropped += cache->nodesDropped();
  if (dropped > 0)
    std::cerr << "diffraction cache: " << dropped << " spots dropped at its " << (SpotCache::memoryLimitBytes() >> 20)
              << " MB cap and computed again (--diffraction-cache-mb)\n";
  return 0;
}

}  // namespace dss::cli
