// What a model file says about its network: architecture, input encoding, the
// sensor it was trained for, training summary and metrics. Torch-free YAML.
#pragma once

#include <array>
#include <stdexcept>
#include <string>
#include <vector>

#include "digital_sun_sensor/eval/uncertainty.h"
#include "digital_sun_sensor/model/angle_correction.h"
#include "digital_sun_sensor/model/arch.h"
#include "digital_sun_sensor/model/input_spec.h"
#include "digital_sun_sensor/model/spot_bias.h"
#include "digital_sun_sensor/model/symmetry.h"

namespace dss {

// A model file that cannot be used; the message names the file and the problem.
class ModelError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct ModelMetadata {
  ArchSpec arch;
  InputSpec input;
  double angle_scale_rad = 0.0;      // network angle output 1.0 = this many radians
  AngleCorrection angle_correction;  // fitted after training (none until then)
  // Geometric head: the correction's change with the mask height, one entry
  // per height fitted (dss calibrate-height; none: the correction stays).
  std::vector<HeightCorrection> height_corrections;
  // Estimates averaged over these mirror images (set after training, by dss
  // calibrate-sigma; the sensor must have the symmetry).
  InferenceSymmetry inference_symmetry = InferenceSymmetry::kNone;
  // Predicted sigma scaled with the image's lit-site count (fitted by dss
  // calibrate-sigma with a constant sigma; inactive otherwise).
  SiteSigmaLaw sigma_site_law;
  // Geometric head: the median weighted spot residual per degree of freedom
  // on the images the model was last calibrated on (dss calibrate-sigma,
  // dss calibrate-unit); 0: not measured. Prediction::spot_mismatch is in
  // its units, and the estimator flags model_mismatch beyond
  // mismatch_threshold of them.
  double mismatch_level = 0.0;
  double mismatch_threshold = 0.0;
  // Geometric head: sigma [rad] of alpha and beta from the uncertainty of
  // the unit calibration's fitted geometry (the fit is the same for every
  // image, so it is not in the network's sigma), added in quadrature to each
  // estimate's; 0 for the design.
  std::array<double, 2> geometry_sigma_rad{};
  // Geometric head, after a unit calibration: each aperture's fitted
  // position variance [um^2, mean of x and y] and the spot noise variance per
  // axis at unit solve weight [um^2], from the same fit. The solve weighs a
  // spot by 1 / (1 / w + variance / noise): one whose aperture the
  // calibration images hardly pinned counts for what is known of it
  // (SensorGeometryImpl::setPositionVariance). Empty: positions exact.
  std::vector<double> aperture_variance_um2;
  double spot_noise_um2 = 0.0;
  // Geometric head: where the network reads a whole spot off the ray
  // trace's, per aperture class and sun angle (dss calibrate-sigma
  // --spot-bias-degree, on the design's images); inactive: nowhere.
  SpotBias spot_bias;
  // YAML map: the unit calibration the geometry holds (dss calibrate-unit:
  // data, images, residuals, fitted parameters); "{}": the nominal design.
  std::string unit_yaml = "{}";
  std::string sensor_name;
  std::string sensor_yaml;    // canonical config (toYaml) the model was made for
  std::string training_yaml;  // YAML map: data, schedule, wall time ("{}" untrained)
  std::string metrics_yaml;   // YAML map: validation figures ("{}" none)
  std::string created_utc;
};

// Metadata of a fresh model for a sensor.
ModelMetadata metadataFor(const SensorConfig& config, const ArchSpec& arch, const HeadOptions& head = {});

std::string metadataToYaml(const ModelMetadata& meta);
// Throws ModelError naming `origin` and the bad key.
ModelMetadata metadataFromYaml(const std::string& yaml_text, const std::string& origin);

// Throws ModelError when `config` is not the sensor the model was made for
// (detector format, mask layout, optics path, sub-FOV classes).
void checkSensorCompatible(const ModelMetadata& meta, const SensorConfig& config, const std::string& origin);

}  // namespace dss
