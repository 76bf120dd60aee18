// The general head's model of the sensor and its solve: the quantities the
// baseline's calibration fits (mask height, offset, rotation, tilt, each
// aperture's position, the cover glass) as named tensors of the model file,
// a differentiable ray trace from the sun angles to every aperture's spot,
// and a weighted Gauss-Newton solve of the angles from the spots the network
// read, with gradients through both (docs/sscnn.md, "Geometric head").
#pragma once

#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

#include <cstdint>
#include <optional>
#include <vector>

#include "digital_sun_sensor/baseline/calibration_model.h"
#include "digital_sun_sensor/model/geometry_design.h"
#include "digital_sun_sensor/model/spot_bias.h"

namespace dss {

// Double tensors, registered as buffers under these names (prefixed
// "geometry." in the model file): the nominal design at creation, a unit's
// own values after a unit calibration.
class SensorGeometryImpl : public torch::nn::Module {
 public:
  // air_above_exit_um: MaskGeometry::air_above_exit_um, fixed by the design.
  SensorGeometryImpl(int apertures, int groups, double air_above_exit_um = 0.0);
  // The design, with offset, rotation and tilt zero. Throws
  // std::invalid_argument naming what does not fit the constructor's counts
  // or is out of range.
  void setDesign(const GeometryDesign& design);
  int apertures() const { return static_cast<int>(apertures_um.size(0)); }
  int groups() const { return static_cast<int>(group_count_); }
  // Spot centres [B, K, 2] (um from the detector centre, +x along columns)
  // of every aperture for sun angles [B, 2] (alpha, beta in rad, double);
  // exact Snell refraction in the glass. Differentiable in the angles and in
  // every geometry tensor.
  torch::Tensor spotsUm(const torch::Tensor& angles_rad) const;
  // The same per group [B, G, 2], with the spot bias added (a constant of
  // the angles' values: no gradient flows through it).
  torch::Tensor groupSpotsUm(const torch::Tensor& angles_rad) const;
  // The geometry in the baseline's terms (a pixel pitch of 1 um, so that its
  // spots are in um), and back: height, offset, rotation, tilt and aperture
  // positions (a unit calibration fits these; glass, groups and fluxes stay).
  MaskGeometry maskGeometry() const;
  // Throws std::invalid_argument for another aperture count or a height <= 0.
  void setMaskGeometry(const MaskGeometry& geometry);
  // The design's mask height, which the model's angle corrections were
  // fitted at: set by setDesign, and for a loaded model from its sensor
  // config (a unit model's tensors hold the unit). nullopt: not set.
  void setDesignHeight(const GeometryDesign& design);
  const std::optional<double>& designHeightUm() const { return design_height_um_; }

  // A unit calibration's uncertainty of each aperture's position [um^2]
  // over the spot noise at unit solve weight [um^2] (ModelMetadata::
  // aperture_variance_um2, spot_noise_um2), per group (flux-weighted): the
  // solve weighs a group's spot by 1 / (1 / w + variance). Empty variances:
  // every position exact. Throws std::invalid_argument for another aperture
  // count, a negative variance or a noise <= 0.
  void setPositionVariance(const std::vector<double>& aperture_variance_um2, double spot_noise_um2);
  const std::vector<double>& groupPositionVariance() const { return group_variance_; }

  // Where the network reads each group's whole spot off the ray trace's
  // (ModelMetadata::spot_bias, its changes with the height included);
  // inactive: nowhere. Throws std::invalid_argument as SpotBias::validate.
  void setSpotBias(const SpotBias& bias);
  // The bias at the geometry's mask height (what groupSpotsUm adds), and at another.
  const SpotBias& spotBias() const { return spot_bias_here_; }
  SpotBias spotBiasAt(double mask_height_um) const;

  torch::Tensor height_um;           // [1]
  torch::Tensor offset_um;           // [2] lateral offset of the mask
  torch::Tensor rotation_rad;        // [1] about the boresight
  torch::Tensor tilt_rad;            // [2] about x, then y
  torch::Tensor apertures_um;        // [K, 2] centres in the mask frame
  torch::Tensor glass_thickness_um;  // [1]
  torch::Tensor glass_index;         // [1]
  torch::Tensor aperture_group;      // [K] (long) the aperture's group
  torch::Tensor aperture_flux;       // [K] relative flux

 private:
  std::int64_t group_count_;
  double air_above_exit_um_ = 0.0;
  std::optional<double> design_height_um_;
  std::vector<double> group_variance_;  // per group, in units of the spot noise per unit weight
  SpotBias spot_bias_;                  // the design's, with its changes
  SpotBias spot_bias_here_;             // at height_um
};
TORCH_MODULE(SensorGeometry);

struct GeometricSolveOptions {
  // Sites farther than this from every predicted spot are read by none
  // (stray light, ghosts, hot pixels away from the spots).
  double gate_um = 100.0;
  // Detector: pixel pitch and half extents, for the edge rule.
  double pitch_um = 1.0;
  int width_px = 1, height_px = 1;
  // Associations from the reference, then from each solve.
  int association_rounds = 2;
  int gauss_newton_iterations = 5;
  // Before associating, search the hypotheses "the image's heaviest site is
  // group g's spot" (one per group) beside the reference for the one whose
  // spots explain the most light and leave the fewest expected spots dark:
  // the association then does not hang on a coarse estimate (inference).
  bool search_reference = false;
  bool symmetric_spots = false;  // ArchSpec::geometric_symmetric_spots
};

struct GeometricSolution {
  // [B, 2] rad (double): Gauss-Newton to convergence without autograd, then
  // one step in the graph (its Jacobian and normal matrix detached), whose
  // gradient is the implicit function's at the solution.
  torch::Tensor angles_rad;
  // [B, 2] log of the diagonal of (J^T W J)^-1 (rad^2 per unit weight),
  // detached: how the spots' weights and the geometry constrain each axis.
  torch::Tensor log_variance;
  // [B] spots read in the final solve (0: the reference is returned).
  torch::Tensor spots_read;
  // [B] RMS distance of the read spots from the geometry's at angles_rad [um].
  torch::Tensor residual_um;
  // [B] the read spots' weighted squared residual per degree of freedom at
  // angles_rad, sum_g w_g |r_g|^2 / (2 spots - 2), 0 with fewer than two spots: in units
  // of the spot noise per unit weight, which the model's mismatch scale
  // calibrates (how far the spots are from any pattern the geometry makes).
  torch::Tensor residual_per_dof;
  // [B] bool: one spot read, and another aperture could have made it
  // (geometric::ImageSolution::lone_spot_ambiguous).
  torch::Tensor lone_spot_ambiguous;
};

// Solves each image's sun angles from its sites: positions site_um [N, 2]
// (double, um from the detector centre), weights [N] (>= 0, differentiable),
// image index [N]. Each site goes to the aperture whose spot the geometry
// puts nearest at the current angles (within the gate), and so to its
// group, starting from
// reference_rad [B, 2]; a spot is its sites' weighted centroid, weighing in
// the solve by its summed weight over its weighted spread (the centroid's
// noise variance goes as spread / sum); a spot with a site on the
// detector's outermost rows or columns is cut: not read while the image has
// a whole one, and read at the vertex of a quadratic fitted to its light
// along the cut axis (its centroid is pulled inward).
GeometricSolution solveGeometry(const SensorGeometryImpl& geometry, const torch::Tensor& site_um,
                                const torch::Tensor& weight, const torch::Tensor& index, std::int64_t batch,
                                const torch::Tensor& reference_rad, const GeometricSolveOptions& options);

}  // namespace dss
