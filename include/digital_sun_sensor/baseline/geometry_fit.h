// Levenberg-Marquardt fit of a pinhole geometry (MaskGeometry: mask height,
// offset, rotation, tilt, each aperture's position) to spots observed at
// known sun directions. The baseline's calibration (calibration_fit) and the
// geometric head's unit calibration (model/unit_calibration) fit through it.
//
// Identifiability: only each aperture's centre in the sensor frame is seen.
// A mask rotation about the boresight or a common offset equals moving every
// aperture, so per-aperture corrections carry a weak prior (they take what the
// common terms cannot explain); a single aperture has no rotation or tilt to
// fit, and a tilt needs three apertures not on a line.
#pragma once

#include <Eigen/Core>
#include <array>
#include <string>
#include <vector>

#include "digital_sun_sensor/baseline/calibration_model.h"

namespace dss {

// One spot seen at a known sun direction.
struct GeometryObservation {
  int sample = 0;  // the image it was seen in (for the caller)
  Eigen::Vector3d sun = Eigen::Vector3d::UnitZ();
  // The apertures whose light makes the spot: one, or a group whose spots
  // overlap and read as one, their flux-weighted mean (fluxes: relative, one
  // per aperture; empty for one aperture).
  std::vector<int> apertures;
  std::vector<double> fluxes;
  Eigen::Vector2d measured_px = Eigen::Vector2d::Zero();
  double weight = 1.0;  // inverse noise variance, relative to the other spots and the prior
};

class GeometryFit {
 public:
  // Parameters: the six globals (height, offset x/y, rotation, tilt x/y;
  // absolute) then per aperture its (dx, dy) from `base`. Those the data
  // cannot determine (see above) stay at `base`'s values; the aperture
  // offsets weigh `prior_weight` x their square in the cost, or aperture k's
  // `aperture_prior_weights[k]` where given (one per aperture; throws
  // std::invalid_argument otherwise).
  GeometryFit(const MaskGeometry& base, double prior_weight, const std::vector<double>& aperture_prior_weights = {});

  Eigen::VectorXd start() const;  // `base`
  MaskGeometry apply(const Eigen::VectorXd& p) const;
  // Names of the free parameters ("height", ..., "aperture_xy").
  std::vector<std::string> freeParameters() const;
  // Predicted spot [px] of an observation, false when no ray reaches it.
  bool predict(const MaskGeometry& g, const GeometryObservation& o, Eigen::Vector2d& spot_px) const;
  // sum of weight x squared residual, plus the prior.
  double cost(const Eigen::VectorXd& p, const std::vector<GeometryObservation>& obs) const;
  // Levenberg-Marquardt from p; returns the iterations used.
  int run(Eigen::VectorXd& p, const std::vector<GeometryObservation>& obs, int max_iterations) const;
  // Weighted squared residual per degree of freedom at p: the noise variance
  // per axis of a spot of weight 1 [px^2].
  double residualVariance(const Eigen::VectorXd& p, const std::vector<GeometryObservation>& obs) const;
  // Covariance of the parameters at p (zero rows and columns where not
  // free): the inverse normal matrix (with the prior) times residualVariance.
  Eigen::MatrixXd covariance(const Eigen::VectorXd& p, const std::vector<GeometryObservation>& obs) const;
  // Per aperture, the variance of its position with the globals held
  // (mean of x and y, px^2): how well its own spots (and the prior) pin it,
  // apart from the offset and rotation that all apertures share; 0 where
  // the apertures are not free.
  std::vector<double> apertureVariances(const Eigen::VectorXd& p, const std::vector<GeometryObservation>& obs) const;
  // Standard errors of the six globals from covariance() (0 where not free).
  static std::array<double, 6> standardErrors(const Eigen::MatrixXd& covariance);
  // Residual length per observation [px] (infinity where no ray reaches).
  std::vector<double> residualNorms(const Eigen::VectorXd& p, const std::vector<GeometryObservation>& obs) const;

 private:
  // Normal equations at p: a = sum w J^T J + prior, b = sum w J^T r - prior p.
  void normalEquations(const Eigen::VectorXd& p, const std::vector<GeometryObservation>& obs, Eigen::MatrixXd& a,
                       Eigen::VectorXd& b) const;

  MaskGeometry base_;
  std::vector<bool> free_;
  std::vector<double> prior_weights_;  // per aperture
};

// Median absolute value x 1.4826 (0 for none).
double robustSigma(std::vector<double> values);

}  // namespace dss
