#include <iomanip>
#include <iostream>
#include <sstream>

#include "commands.h"
#include "digital_sun_sensor/baseline/calibration_fit.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/ros/dataset_source.h"
#include "digital_sun_sensor/sim/geometry.h"
#include "lab_coverage.h"
#include "progress.h"

namespace dss::cli {

int runCalibrate(int argc, char** argv) {
  Args args("dss calibrate",
            "Fits the conventional baseline (centroids + pinhole/refraction geometry + residual polynomial)\n"
            "to labelled images of ONE sensor and writes its calibration YAML.",
            {
                {"data", "BAG", "dataset bag(s) of /sun_sensor/image + /sun_sensor/truth", "", true, true},
                {"out", "CALIB", "calibration YAML to write (atomically)", "", true, false},
                {"sensor", "CFG", "sensor design (default: the config embedded in the bag)", "", false, false},
                {"set", "KEY=VALUE", "override a key of --sensor", "", false, true},
                {"method", "M", "centroid: cog | weighted | gaussian", "weighted", false, false},
                {"degree", "D", "residual polynomial degree (0: none)", "3", false, false},
                {"aperture-prior-um", "U", "prior sigma of per-aperture position corrections", "20", false, false},
                {"max-images", "N", "use at most N images (0: all)", "0", false, false},
            });
  if (!args.parse(argc, argv, 2)) return 0;
  const DatasetBagReader reader(args.all("data"));
  if (const int instances = instancesFromBagInfo(reader); instances > 1)
    throw std::runtime_error("the bag was rendered from " + std::to_string(instances) +
                             " sensor instances; a calibration fits one sensor (generate with --instances 1)");
  std::optional<SensorConfig> config;
  if (args.has("sensor")) {
    config = loadSensorConfig(args.get("sensor"), args.all("set"));
  } else {
    config = sensorFromBagInfo(reader);
    if (!config) throw UsageError("dss calibrate: the bag carries no sensor config (dataset_info); pass --sensor CFG");
  }

  Calibration calibration = Calibration::nominalOf(*config);
  try {
    calibration.extraction.method = parseCentroidMethod(args.get("method"));
  } catch (const std::invalid_argument& e) {
    throw UsageError(std::string("dss calibrate: --method: ") + e.what());
  }
  CalibrationFitOptions options;
  options.polynomial_degree = static_cast<int>(args.getInt("degree"));
  options.aperture_prior_um = args.getDouble("aperture-prior-um");
  if (options.polynomial_degree < 0 || options.polynomial_degree > 8)
    throw UsageError("dss calibrate: --degree must be 0..8");
  const auto max_images = static_cast<std::uint64_t>(args.getInt("max-images"));

  std::vector<CalibrationSample> samples;
  std::vector<double> lab_alpha_rad, lab_beta_rad;
  Progress progress("calibrate: spots",
                    max_images ? std::min(max_images, reader.imageMessages()) : reader.imageMessages());
  const BagReadStats stats = reader.forEach([&](const LabelledImage& item) {
    checkImageFitsSensor(item, *config);
    if (item.truth.valid) {
      samples.push_back(
          {sunVectorFromAngles(item.truth.alpha, item.truth.beta), extractSpots(item.image, calibration.extraction)});
      lab_alpha_rad.push_back(item.truth.alpha);
      lab_beta_rad.push_back(item.truth.beta);
    }
    progress.update(item.index + 1);
    return max_images == 0 || item.index + 1 < max_images;
  });
  progress.finish();
  std::cerr << "read " << describe(stats) << "\n";
  if (samples.empty()) throw std::runtime_error("no usable labelled images in the data");
  const FieldCoverage coverage = noteLabCoverage(*config, lab_alpha_rad, lab_beta_rad);

  const CalibrationFitReport report = fitCalibration(samples, calibration, options);
  saveCalibration(args.get("out"), calibration);

  const auto& g = calibration.geometry;
  std::cerr << "fitted " << report.observations << " spots of " << report.images << " images (" << report.outliers
            << " outliers dropped): residual " << report.rms_px_design << " px (design) -> " << report.rms_px_fitted
            << " px; angle RMS " << report.angle_rms_deg_geometry << " deg (geometry) -> " << report.angle_rms_deg
            << " deg (with degree-" << calibration.polynomial.degree << " polynomial)\n"
            << "wrote " << args.get("out") << "\n";
  std::ostringstream json;
  json << std::setprecision(8) << "{\"images\": " << report.images << ", \"observations\": " << report.observations
       << ", \"outliers\": " << report.outliers << ", \"rms_px_design\": " << report.rms_px_design
       << ", \"rms_px_fitted\": " << report.rms_px_fitted
       << ", \"centroid_sigma_px\": " << calibration.centroid_sigma_px
       << ", \"angle_rms_deg_geometry\": " << report.angle_rms_deg_geometry
       << ", \"angle_rms_deg\": " << report.angle_rms_deg << ", \"angle_max_deg\": " << report.angle_max_deg
       << ", \"height_um\": " << g.height_um << ", \"offset_x_um\": " << g.offset_x_um
       << ", \"offset_y_um\": " << g.offset_y_um << ", \"rotation_deg\": " << g.rotation_rad * kDegPerRad
       << ", \"tilt_x_deg\": " << g.tilt_x_rad * kDegPerRad << ", \"tilt_y_deg\": " << g.tilt_y_rad * kDegPerRad
       << ", \"polynomial_degree\": " << calibration.polynomial.degree
       << ", \"field_ninths_empty\": " << coverage.emptyCells() << "}";
  std::cout << json.str() << std::endl;
  return 0;
}

}  // namespace dss::cli
