// Spot-to-aperture association for single, multi-aperture and coded masks.
// Every (bright spot, aperture) pairing is a hypothesis fixing the sun
// direction; the hypothesis whose predicted pattern explains the most
// detections wins. A spot whose centre should be on the detector but is not
// seen counts against it, weighted by how often that aperture is seen at all
// (calibration); a detection of a rarely seen aperture counts less; spot size
// must agree with aperture diameter. The winner is refined on all matches. Spots cut by the detector edge are never
// used for the solution (biased centroids), but a hypothesis that explains
// them scores higher: on a regular lattice they are what tells a shift of one
// pitch apart.
#pragma once

#include <optional>
#include <vector>

#include "digital_sun_sensor/baseline/calibration_model.h"
#include "digital_sun_sensor/baseline/spot_extraction.h"

namespace dss {

struct AssociationOptions {
  double gate_px = 8.0;          // a detection within this of a predicted spot matches it
  double edge_margin_px = 40.0;  // spot radius: gate for edge-cut detections
  double fov_alpha_rad = 0.08;   // hypotheses outside the field of view (plus margin) are dropped
  double fov_beta_rad = 0.08;
  int anchors = 3;  // brightest spots tried as anchors
  // Per aperture: how often its spot is seen when its centre is on the
  // detector (from calibration; empty: always). Under a high on-chip
  // threshold a slightly dimmer aperture is rarely seen, so its absence is no
  // evidence against a hypothesis, while a bright one's absence is.
  std::vector<double> detection_probability;
  double size_weight = 4.0;  // per squared log-ratio of spot area vs aperture area

  // Gate, margins and field of view from the sensor design.
  static AssociationOptions forSensor(const SensorConfig& config, const MaskGeometry& geometry);
};

struct Association {
  std::vector<SpotObservation> observations;  // matched spots
  std::vector<int> spot_indices;              // into the detected spots, parallel to observations
  SunSolution solution;
  int misses = 0;
};

// Best association, or nullopt when no hypothesis explains any spot.
std::optional<Association> associateSpots(const MaskGeometry& geometry, const std::vector<DetectedSpot>& spots,
                                          const AssociationOptions& options);

// Association when the sun direction is known (calibration data): each
// detected spot goes to the aperture predicted nearest it, within the gate.
Association associateWithKnownSun(const MaskGeometry& geometry, const std::vector<DetectedSpot>& spots,
                                  const Eigen::Vector3d& sun, double gate_px);

}  // namespace dss
