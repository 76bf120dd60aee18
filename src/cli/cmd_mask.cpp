#include <iostream>

#include "commands.h"
#include "digital_sun_sensor/common/file_io.h"
#include "digital_sun_sensor/sim/random_mask.h"

namespace dss::cli {

int runMask(int argc, char** argv) {
  auto specs = sensorOptions();
  const RandomMaskOptions defaults;
  specs.insert(
      specs.end(),
      {
          {"apertures", "N", "apertures to draw (1..64)", std::to_string(defaults.apertures), false, false},
          {"seed", "S", "seed of the draw", "1", false, false},
          {"diameter-um", "UM", "aperture diameter (0: the base config's first aperture's)", "0", false, false},
          {"diameter-spread", "F", "diameters uniform within +-F of it (0: all alike)",
           defaultText(defaults.diameter_spread), false, false},
          {"min-separation", "SPOTS", "least distance between apertures, in spot diameters",
           defaultText(defaults.min_separation_spots), false, false},
          {"min-whole-spots", "N", "spots wholly on the detector at every attitude of the field",
           std::to_string(defaults.min_whole_spots), false, false},
          {"min-lit-spots", "N",
           "of those, spots above the threshold in the design's noise-free images over the field (rendered, "
           "seconds per draw; 0: not checked)",
           std::to_string(defaults.min_lit_spots), false, false},
          {"name", "NAME", "sensor name (default: BASE_random_SEED)", "", false, false},
          {"out", "YAML", "sensor config to write", "", true, false},
      });
  Args args("dss mask",
            "Draws a seeded irregular mask within a sensor config (detector, height, field and readout kept) and "
            "writes the config; prints a JSON summary. For testing estimators on masks nobody tuned for.",
            specs);
  if (!args.parse(argc, argv, 2)) return 0;
  const SensorConfig base = loadSensorFromArgs(args);
  RandomMaskOptions options;
  options.apertures = static_cast<int>(args.getInt("apertures"));
  options.diameter_um = args.getDouble("diameter-um");
  options.diameter_spread = args.getDouble("diameter-spread");
  options.min_separation_spots = args.getDouble("min-separation");
  options.min_whole_spots = static_cast<int>(args.getInt("min-whole-spots"));
  options.min_lit_spots = static_cast<int>(args.getInt("min-lit-spots"));
  const auto seed = static_cast<std::uint64_t>(args.getInt("seed"));
  const RandomMask mask = drawRandomMask(base, options, seed, args.get("name"));
  // The written config must read back as itself (the YAML reader validates it).
  const std::string yaml = "# Drawn by: dss mask --apertures " + std::to_string(options.apertures) + " --seed " +
                           std::to_string(seed) + " (base: " + base.name + ")\n" + toYaml(mask.config);
  parseSensorConfig(yaml, args.get("out"));
  writeFileAtomic(args.get("out"), yaml);
  std::cout << "{\"sensor\":\"" << mask.config.name << "\",\"apertures\":" << mask.config.mask.apertures.size()
            << ",\"spot_diameter_um\":" << mask.spot_diameter_um << ",\"min_spacing_um\":" << mask.min_spacing_um
            << ",\"min_whole_spots\":" << mask.min_whole_spots << ",\"min_lit_spots\":" << mask.min_lit_spots
            << ",\"draws\":" << mask.draws << ",\"out\":\"" << args.get("out") << "\"}" << std::endl;
  return 0;
}

}  // namespace dss::cli
