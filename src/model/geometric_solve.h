// The geometric head's solve for one image in plain double arithmetic: the
// search over association hypotheses and the Gauss-Newton iterations, which
// need no gradient (model/geometric_head.cpp takes the last step in the
// graph). Thousands of tiny tensor ops cost more than the arithmetic.
#pragma once

#include <Eigen/Core>
#include <vector>

#include "digital_sun_sensor/baseline/calibration_model.h"
#include "digital_sun_sensor/model/spot_bias.h"

namespace dss {
class SensorGeometryImpl;
struct Model;
}  // namespace dss

namespace dss::geometric {

struct Design {
  MaskGeometry mask;         // with a pixel pitch of 1: spots in um
  std::vector<int> group;    // per aperture
  std::vector<double> flux;  // per aperture
  int groups = 1;
  SpotBias spot_bias;  // added to the group spots (SensorGeometryImpl::spotBias)
};

// The geometric head's geometry tensors as the plain solve takes them
// (model/geometric_head.cpp).
Design designOf(const SensorGeometryImpl& geometry);

struct Options {
  double gate_um = 100.0;
  double pitch_um = 1.0;
  int width_px = 1, height_px = 1;
  int rounds = 2, iterations = 5;
  bool search = false;
  // Whole spots read at their point of symmetry (baseline/symmetry_centre.h),
  // not their weighted centroid, where readSpots fits (fit_cut).
  bool symmetric_spots = false;
  // Per group: the uncertainty of its spot's position from the geometry, in
  // units of the spot noise per unit weight (SensorGeometryImpl::
  // groupPositionVariance); empty: none.
  std::vector<double> group_variance;
};

// The detector and gate of a geometric-head model, as its solve takes them
// (model/unit_calibration.cpp).
Options solveOptions(const Model& model);

struct Site {
  Eigen::Vector2d um;
  double weight = 0.0;
};

struct ImageSolution {
  Eigen::Vector2d angles_rad = Eigen::Vector2d::Zero();
  std::vector<int> group;                 // per site: its group, or -1 beyond the gate
  std::vector<Eigen::Vector2d> read_um;   // per site: where its spot reads it
  std::vector<double> weight;             // per group: its weight in the solve (0: not read)
  std::vector<Eigen::Matrix2d> jacobian;  // per group: d(spot um)/d(angles) at the solution
  Eigen::Matrix2d normal_inverse = Eigen::Matrix2d::Zero();
  // The search read one spot, and a hypothesis at least kDistinctDeg away
  // that puts it on another aperture explains the light as well, on a mask
  // whose apertures differ in size: only dark spots spoke against it, and a
  // threshold relative to the brightest pixel leaves the spots of dimmer
  // apertures dark. Which aperture made the spot is not known.
  bool lone_spot_ambiguous = false;
  static constexpr double kDistinctDeg = 0.1;
};

// The spots as the sites show them at given angles: per site its group and
// squared distance from its nearest aperture's spot; per group the summed
// weight, weighted centroid and spread of its sites within `radius_um`, and
// whether one of them lies on the detector's outermost rows or columns (cut).
// With `fit_cut`, a cut spot's centre along the axes it is cut is the vertex
// of an isotropic quadratic fitted to its sites' weights (its plain centroid
// is pulled inward), and its sites are read moved by the difference
// (`read_um`: where each site is read). With the options' symmetric_spots
// (and `fit_cut`), a whole spot's sites are read moved alike so that their
// weighted centroid is the spot's point of symmetry.
struct Reading {
  std::vector<int> group;
  std::vector<double> distance2;
  std::vector<Eigen::Vector2d> read_um;
  std::vector<double> sum, spread;
  std::vector<Eigen::Vector2d> centroid;
  std::vector<char> cut;
};
Reading readSpots(const Design& design, const std::vector<Site>& sites, const Eigen::Vector2d& angles, double radius_um,
                  const Options& options, bool fit_cut = true);

// Weight of each group in the solve: its summed weight over its spread (the
// centroid's noise variance goes as spread / sum), w / (1 + w v) with the
// options' group variance v; whole spots only where the image has one.
std::vector<double> solveWeights(const Reading& r, const Options& options);

// Spots of every group [um] for the angles (far away where no ray reaches),
// the design's spot bias added.
std::vector<Eigen::Vector2d> groupSpots(const Design& design, const Eigen::Vector2d& angles_rad);

ImageSolution solveImage(const Design& design, const std::vector<Site>& sites, const Eigen::Vector2d& reference_rad,
                         const Options& options);

}  // namespace dss::geometric
