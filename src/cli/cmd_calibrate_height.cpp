// dss calibrate-height: fits how a geometric-head family model's angle
// correction changes with the mask height (src/train/bias_calibration), on
// images of its design with the mask moved, and writes the model.
#include <cmath>
#include <iostream>

#include "bag_reading.h"
#include "commands.h"
#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/sparse/threads.h"
#include "digital_sun_sensor/train/bias_calibration.h"

namespace dss::cli {

int runCalibrateHeight(int argc, char** argv) {
  Args args(
      "dss calibrate-height",
      "Fits how a family model's angle correction changes with the mask height, for units whose mask sits "
      "higher or lower than the design's (a unit calibration or an in-flight refit finds the height; an air gap "
      "above a glass window or a thinner window shapes the spots otherwise, which moves where the network reads "
      "them): on labelled images of the design with its mask moved by --height-change-um (dss generate --set "
      "mask.height_mm=...), the model's geometry moved alike, the correction's change is fitted (Legendre "
      "polynomials of the angles, degree chosen by two-fold cross-validation) and recorded for height changes of "
      "that sign, in proportion; with a spot bias in the model, its change at that height likewise. Run once per sign "
      "on the family model (geometric head), before calibrating "
      "units; writes the model atomically and prints one JSON line.",
      {
          {"model", "MODEL", "family model (geometric head, its design's geometry)", "", true, false},
          {"data", "BAG", "labelled bag(s) of the design with the mask moved", "", true, true},
          {"height-change-um", "UM", "how far the images' mask sits above (+) or below (-) the design's", "", true,
           false},
          {"out", "MODEL", "model file to write (may be --model)", "", true, false},
          {"max-images", "N", "use at most N images, over all bags (0: all)", "5000", false, false},
          {"correction-degree", "D",
           "highest degree of the change (0.." + std::to_string(AngleCorrection::kMaxDegree) + ")", "16", false, false},
          {"spot-bias-degree", "D|none",
           "with a spot bias in the model (calibrate-sigma --spot-bias-degree): highest degree of its change at this "
           "height, fitted on the same images (0.." +
               std::to_string(AngleCorrection::kMaxDegree) + "; none: the bias stays with the height)",
           "10", false, false},
      });
  if (!args.parse(argc, argv, 2)) return 0;
  const double height_change_um = args.getDouble("height-change-um");
  if (!std::isfinite(height_change_um) || height_change_um == 0.0)
    throw UsageError("dss calibrate-height: --height-change-um must be non-zero, not " + args.get("height-change-um"));
  const auto degree = static_cast<int>(args.getInt("correction-degree"));
  if (degree < 0 || degree > AngleCorrection::kMaxDegree)
    throw UsageError("dss calibrate-height: --correction-degree must be 0.." +
                     std::to_string(AngleCorrection::kMaxDegree) + ", not " + args.get("correction-degree"));
  int spot_bias_degree = AngleCorrection::kNone;
  if (args.get("spot-bias-degree") != "none") {
    spot_bias_degree = static_cast<int>(args.getInt("spot-bias-degree"));
    if (spot_bias_degree < 0 || spot_bias_degree > AngleCorrection::kMaxDegree)
      throw UsageError("dss calibrate-height: --spot-bias-degree must be 'none' or 0.." +
                       std::to_string(AngleCorrection::kMaxDegree) + ", not " + args.get("spot-bias-degree"));
  }
  sparse::configureThreads(1, 2);
  Model model = loadModel(args.get("model"));
  if (!model.meta.arch.geometric_head)
    throw UsageError("dss calibrate-height: " + args.get("model") + " has no geometric head");
  SensorConfig moved = parseSensorConfig(model.meta.sensor_yaml, args.get("model") + " (sensor)");
  moved.mask.height_mm += height_change_um / 1000.0;
  const auto max_images = static_cast<std::uint64_t>(args.getInt("max-images"));
  const TrainingData data = readLabelledBags("calibrate-height", args.all("data"), moved, {}, max_images);
  HeightCalibration fit;
  try {
    fit = calibrateHeightCorrection(model, data.samples, height_change_um,
                                    max_images ? max_images : data.samples.size(), degree, spot_bias_degree);
  } catch (const std::invalid_argument& e) {
    throw UsageError(std::string("dss calibrate-height: ") + e.what());
  }
  const BiasCalibration& c = fit.correction;
  saveModel(model, args.get("out"));
  std::cerr << "wrote " << args.get("out") << "\n";
  std::cout << "{\"command\": \"calibrate-height\", \"model\": \"" << args.get("out")
            << "\", \"height_change_um\": " << height_change_um << ", \"samples\": " << c.samples
            << ", \"outliers\": " << c.outliers << ", \"degree\": " << c.degree
            << ", \"rms_alpha_before_deg\": " << c.rms_alpha_before_deg
            << ", \"rms_beta_before_deg\": " << c.rms_beta_before_deg
            << ", \"rms_alpha_after_deg\": " << c.rms_alpha_after_deg
            << ", \"rms_beta_after_deg\": " << c.rms_beta_after_deg << ", \"cv_rms_deg\": [";
  for (std::size_t k = 0; k < c.cross_validated_rms_deg.size(); ++k)
    std::cout << (k ? ", " : "") << c.cross_validated_rms_deg[k];
  std::cout << "]";
  if (fit.spot_bias) {
    const SpotBiasFit& b = *fit.spot_bias;
    std::cout << ", \"spot_bias_degree\": " << b.bias.degree << ", \"spot_bias_spots\": " << b.spots
              << ", \"spot_bias_rms_um_before\": " << b.rms_before_um
              << ", \"spot_bias_rms_um_after\": " << b.rms_after_um << ", \"spot_bias_cv_rms_um\": [";
    for (std::size_t k = 0; k < b.cross_validated_rms_um.size(); ++k)
      std::cout << (k ? ", " : "") << b.cross_validated_rms_um[k];
    std::cout << "]";
  }
  std::cout << "}" << std::endl;
  return 0;
}

}  // namespace dss::cli
