#include <cmath>
#include <iostream>
#include <opencv2/imgcodecs.hpp>

#include "commands.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/sim/geometry.h"
#include "digital_sun_sensor/sim/renderer.h"

namespace dss::cli {

int runRender(int argc, char** argv) {
  auto specs = sensorOptions();
  specs.insert(specs.end(), {
                                {"alpha-deg", "DEG", "sun angle alpha = atan2(s_x, s_z)", "0", false, false},
                                {"beta-deg", "DEG", "sun angle beta = atan2(s_y, s_z)", "0", false, false},
                                {"seed", "S", "sensor draw and noise seed", "1", false, false},
                                {"raw", "", "skip on-chip thresholding", "", false, false},
                                {"out", "PNG", "output image (8 or 16 bit PNG)", "", true, false},
                            });
  Args args("dss render", "Renders one image for a sun direction and writes it as a PNG; prints its truth as JSON.",
            specs);
  if (!args.parse(argc, argv, 2)) return 0;
  const SensorConfig config = loadSensorFromArgs(args);
  const auto seed = static_cast<std::uint64_t>(args.getInt("seed"));
  const Renderer renderer(SensorInstance::draw(config, seed));
  RenderOptions options;
  options.threshold = !args.has("raw");
  ImageTruth truth;
  const cv::Mat image =
      renderer.render(sunVectorFromAngles(degToRad(args.getDouble("alpha-deg")), degToRad(args.getDouble("beta-deg"))),
                      deriveSeed(seed, 0), &truth, options);
  if (!cv::imwrite(args.get("out"), image)) throw std::runtime_error("cannot write '" + args.get("out") + "'");
  int on = 0;
  for (const auto& s : truth.spots) on += s.on_detector ? 1 : 0;
  std::cout << "{\"sensor\":\"" << config.name << "\",\"alpha_rad\":" << truth.alpha_rad
            << ",\"beta_rad\":" << truth.beta_rad << ",\"subfov_class\":" << truth.subfov_class
            << ",\"spots_on_detector\":" << on << ",\"exposure_s\":" << truth.exposure_s
            << ",\"nonzero_pixels\":" << cv::countNonZero(image) << "}" << std::endl;
  return 0;
}

}  // namespace dss::cli
