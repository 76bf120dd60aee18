// Where the network reads a whole spot, relative to where the geometric
// head's ray trace puts it, per class of apertures (one size: equal flux),
// as a smooth function of the sun angles. A diffraction spot cut by the
// detector's threshold is read off its geometric centre by an amount that
// depends on its aperture's size and the angle of incidence (wide_ma: 0.018
// px RMS for the 30 um apertures about the mean of all sizes, 0.006 px for
// the 46 um ones). The model's smooth angle correction takes the mean over
// the spots an image shows; a unit calibration, which fits each aperture's
// position to its spots, took each class's departure from that mean into
// the apertures at the angles its lab images saw and carried it to every
// other angle (the design itself, calibrated as a unit on 25 of its own
// images: 1.2 x its error). That departure is the bias: the head adds it to
// its predicted spots, and the unit fit subtracts it from the spots it reads.
// Torch-free.
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <vector>

#include "digital_sun_sensor/model/angle_correction.h"

namespace dss {

struct Model;
struct UnitImage;

// How the bias changes with the mask height: an air gap under the mask
// spreads a spot at wide angles otherwise, which moves where the network
// reads it (fitted at the design's height only, the bias declined 2 % of an
// air-gap unit's images model_mismatch, against 0.5 % without it). Fitted on
// images of the design with its mask moved by `height_change_um` (dss
// calibrate-height), relative to the design's bias.
struct SpotBiasChange {
  double height_change_um = 0.0;
  int degree = AngleCorrection::kNone;          // kNone: the bias stays at this height
  std::vector<std::vector<double>> x_um, y_um;  // as SpotBias's
};

struct SpotBias {
  // Total Legendre degree (AngleCorrection::terms of the angles over
  // angle_scale_rad); kNone: no bias.
  int degree = AngleCorrection::kNone;
  double angle_scale_rad = 0.0;
  std::vector<int> group_class;  // per group of the head: its class
  // Per class, AngleCorrection::termCount(degree) coefficients [um] of the
  // bias along x and along y.
  std::vector<std::vector<double>> x_um, y_um;
  // The design's changes with the mask height, one per height fitted.
  std::vector<SpotBiasChange> by_height;

  bool active() const { return degree != AngleCorrection::kNone; }
  // Adds each group's bias at the sun angles [rad] to its spot [um] (the
  // design's: take at() first for another height).
  void addTo(const Eigen::Vector2d& angles_rad, std::vector<Eigen::Vector2d>& group_spots_um) const;
  // The bias of a geometry whose mask height differs from the design's by
  // `height_change_um`: the design's plus its changes interpolated in the
  // height as the angle correction's (heightInterpolation), without entries.
  SpotBias at(double height_change_um) const;
  // Throws std::invalid_argument naming what does not fit a head of `groups` groups.
  void validate(int groups) const;
};

// Classes of the head's groups: those whose flux is within 1 % of each
// other's share one (apertures of one size, whose spots have one shape).
std::vector<int> spotBiasClasses(const std::vector<double>& group_flux);

struct SpotBiasFit {
  SpotBias bias;
  std::size_t spots = 0;  // whole spots fitted
  // Weighted RMS [um] of the spots' offsets from the ray trace's at the
  // uncorrected angles, without the bias and with it; per candidate degree
  // from none (index 0) to the maximum, the two-fold cross-validated RMS the
  // degree was chosen by.
  double rms_before_um = 0.0, rms_after_um = 0.0;
  std::vector<double> cross_validated_rms_um;
};

// Fits the spot bias of a model with a geometric head, at its design, to
// labelled images of the design (readUnitImages): each whole spot the
// network reads against the ray trace's at the angles from which the model's
// corrections give the true ones (uncorrectedAngles: there the solve
// balances the spots, so the bias is each class's departure from their
// mean, which the angle correction keeps), weighed as the solve weighs it,
// the degree (none, 0..max_degree) chosen by two-fold cross-validation (even
// and odd images). The model's own bias is left out of the readings; the caller
// sets the result (setSpotBias); a class with fewer whole spots than a
// degree's terms keeps no bias at that degree. Throws std::invalid_argument
// without a geometric head, with max_degree outside
// 0..AngleCorrection::kMaxDegree or without a whole spot.
// With `change_from_model_bias` the readings are taken against the ray
// trace plus the bias the model's geometry adds (at its mask height), and
// the result is the change of that bias at this height, without entries
// (calibrateHeightCorrection).
SpotBiasFit fitSpotBias(const Model& model, const std::vector<UnitImage>& images, int max_degree,
                        bool change_from_model_bias = false);

// Sets the spot bias (its changes with the height included) in the model's
// metadata and its head's geometry. Throws std::invalid_argument as
// SpotBias::validate.
void setSpotBias(Model& model, const SpotBias& bias);

}  // namespace dss
