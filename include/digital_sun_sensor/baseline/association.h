// Spot-to-aperture association for single, multi-aperture and coded masks.
// Every (bright spot, aperture) pairing is a hypothesis fixing the sun
// direction; the hypothesis whose predicted spot pattern explains the most
// detected spots (a missing spot where one should be visible counts against
// it; so does a spot whose size disagrees with its aperture's diameter) wins
// and is refined on all its matches. Spots cut by the detector edge are never
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
  double miss_weight = 0.5;
  double edge_weight = 0.5;  // per edge-cut detection a predicted spot explains
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
