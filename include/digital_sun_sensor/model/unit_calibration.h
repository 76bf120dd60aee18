// Calibration of a built unit (dss calibrate-unit) and the spot-mismatch
// level that tells when a model's geometry does not describe the unit it
// sees. Both need a model with a geometric head. Torch-free header.
//
// A unit calibration refits the head's geometry (mask height, offset,
// rotation, tilt, each aperture's position: baseline/geometry_fit, which says
// what the data can determine) to labelled images of the unit with the
// network frozen: per image, the spots the network reads (its site weights,
// associated through the geometry) against the spots the geometry puts at
// the angles from which the head's learned correction gives the true ones,
// weighed as the solve weighs them. The network, its correction and the
// sigma stay as trained; the fitted geometry's own uncertainty is added to
// the sigma (ModelMetadata::geometry_sigma_rad).
#pragma once

#include <array>
#include <cstddef>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "digital_sun_sensor/baseline/calibration_model.h"
#include "digital_sun_sensor/sim/sensor_config.h"
#include "digital_sun_sensor/train/training_set.h"

namespace dss {

struct Model;

// One image of a unit as the frozen network reads it (its lit sites, um
// from the detector centre, with the solve's weight of each) and the true
// or reference angles: what a unit calibration fits the geometry to.
struct UnitImage {
  std::vector<Eigen::Vector2d> site_um;
  std::vector<double> site_weight;
  double alpha_rad = 0.0, beta_rad = 0.0;
};

struct UnitCalibrationOptions {
  double aperture_prior_um = 20.0;  // per-aperture position prior (gauge fixing)
  double outlier_sigmas = 5.0;      // spots whose weighted residual exceeds this many robust sigmas are dropped
  int max_iterations = 100;
  std::size_t max_samples = 0;  // evenly spaced; 0: all
};

struct UnitCalibrationReport {
  int images = 0;
  int images_used = 0;           // with at least one whole spot read
  std::vector<bool> image_used;  // per image given to fitUnitGeometry
  // calibrateUnit: the samples with a whole spot in the fit, what a smooth
  // angle correction may be fitted to (a spot cut by the detector's edge
  // has a bias of its own, which no smooth function of the angles takes).
  std::vector<const SparseSample*> whole_spot_samples;
  int spots = 0;  // fitted
  int outliers = 0;
  int iterations = 0;
  std::vector<std::string> free_parameters;
  // Spots the network reads against the geometry's at the true angles
  // (weighted RMS, um), and the model's angle error on these images (RMS per
  // axis, deg), with the geometry before and after.
  double spot_rms_um_before = 0.0, spot_rms_um_after = 0.0;
  double angle_rms_deg_before = 0.0, angle_rms_deg_after = 0.0;
  MaskGeometry before, after;  // um (pitch 1)
  // Standard errors of the fitted globals (height, offset x/y [um], rotation,
  // tilt x/y [rad]; 0 where not free), from the fit's normal matrix and
  // residuals.
  std::array<double, 6> standard_errors{};
  // Sigma [rad] of alpha and beta from the fitted geometry's uncertainty
  // (set in the model as ModelMetadata::geometry_sigma_rad).
  std::array<double, 2> geometry_sigma_rad{};
  // Per aperture, the standard deviation of its fitted position [um]
  // (ModelMetadata::aperture_variance_um2): large where no image showed its
  // spot whole.
  std::vector<double> aperture_sigma_um;

  std::string toYaml() const;  // a YAML map, stored in the model (ModelMetadata::unit_yaml)
};

// The error a model whose geometry is its design's makes on a unit built to
// `tolerances`: the RMS change per axis [rad] of the solved angles of up to
// 100 of the labelled images (evenly spaced) when solved through geometries
// drawn from them (height, offset, rotation, tilt, aperture positions; fixed
// seed). A family model meant for units it
// was not calibrated on carries it as its geometry sigma (dss calibrate-sigma
// --unit-tolerances), which a unit calibration replaces by its fit's own.
std::array<double, 2> unitToleranceSigma(const Model& model, const TrainingSet& data, const AsBuiltConfig& tolerances);

// The network's reading of images of the unit (checked against the model's
// input spec; images without a lit pixel left out) with their reference
// angles [rad]. Throws std::invalid_argument for a count mismatch or a bad image.
std::vector<UnitImage> readUnitImages(const Model& model, const std::vector<cv::Mat>& images,
                                      const std::vector<std::array<double, 2>>& reference_rad);

// The same for labelled samples (encoded with the model's input spec; at
// most `max_samples`, evenly spaced, 0: all), their truth as the reference,
// with the model's own estimate of each [rad] in `estimates` when given.
std::vector<UnitImage> readUnitImages(const Model& model, const TrainingSet& data, std::size_t max_samples,
                                      std::vector<std::array<double, 2>>* estimates = nullptr);

// Per image the solve's angles [rad] from which the head's learned
// correction and the model's angle correction (at its geometry's mask
// height) give the image's reference angles: where its spots are compared
// with the geometry's.
std::vector<Eigen::Vector2d> uncorrectedAngles(const Model& model, const std::vector<UnitImage>& images);

// Fits the model's geometry, from its current values, to these images, and
// sets the model's geometry sigma from the fit (the report without the
// angle errors). Throws std::invalid_argument
// without a geometric head or with too few spots.
UnitCalibrationReport fitUnitGeometry(Model& model, const std::vector<UnitImage>& images,
                                      const UnitCalibrationOptions& options = {});

// Fits the unit's geometry into `model` from labelled images of the unit
// (encoded with the model's input spec), widens the model's input envelope
// to hold those images, and records the report, with `data_description`, in
// the model's metadata. Throws std::invalid_argument
// for a model without a geometric head, data of another input spec, or too
// few spots to fit.
UnitCalibrationReport calibrateUnit(Model& model, const TrainingSet& data, const std::string& data_description,
                                    const UnitCalibrationOptions& options = {});

struct MismatchCalibration {
  std::size_t samples = 0;        // with two or more spots read
  double level = 0.0;             // median weighted residual per degree of freedom
  double threshold = 0.0;         // in units of the level
  double flagged_fraction = 0.0;  // of these samples beyond the threshold
};

// Sets the model's spot-mismatch level (ModelMetadata::mismatch_level: the
// median weighted spot residual per degree of freedom on these images) and
// its threshold (`threshold_factor` x the 99.5th percentile, in units of the
// level). Throws std::invalid_argument without a geometric head or with no
// image of two spots.
MismatchCalibration calibrateSpotMismatch(Model& model, const TrainingSet& data, std::size_t max_samples,
                                          double threshold_factor = 2.0);

}  // namespace dss
