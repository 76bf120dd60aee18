#include "digital_sun_sensor/baseline/centroid_estimator.h"

#include <Eigen/Dense>
#include <algorithm>

#include "digital_sun_sensor/common/estimate_status.h"
#include "digital_sun_sensor/sim/geometry.h"

namespace dss {

CentroidEstimator::CentroidEstimator(Calibration calibration)
    : calibration_(std::move(calibration)),
      input_(inputSpecFor(calibration_.sensor)),
      association_(AssociationOptions::forSensor(calibration_.sensor, calibration_.geometry)) {
  association_.detection_probability = calibration_.detection_rate;
}

std::vector<SunEstimate> CentroidEstimator::estimate(const std::vector<cv::Mat>& images) {
  std::vector<SunEstimate> out;
  out.reserve(images.size());
  for (const auto& image : images) out.push_back(estimateOne(image));
  return out;
}

SunEstimate CentroidEstimator::estimateOne(const cv::Mat& image, std::vector<DetectedSpot>* spots_out) const {
  SunEstimate est;
  est.status = input_.badImageStatus(image);
  if (!est.status.empty()) return est;
  const std::vector<DetectedSpot> spots = extractSpots(image, calibration_.extraction);
  if (spots_out) *spots_out = spots;
  if (spots.empty()) {
    est.status = status::kNoSun;
    return est;
  }
  if (std::all_of(spots.begin(), spots.end(), [](const DetectedSpot& s) { return s.touches_edge; })) {
    est.status = status::kSpotAtEdge;
    return est;
  }
  const MaskGeometry& geometry = calibration_.geometry;
  const auto association = associateSpots(geometry, spots, association_);
  if (!association) {
    est.status = status::kNoMatch;
    return est;
  }
  const SunSolution& s = association->solution;
  const Eigen::Vector2d correction = calibration_.polynomial.correction(s.alpha_rad, s.beta_rad);
  est.alpha_rad = s.alpha_rad + correction.x();
  est.beta_rad = s.beta_rad + correction.y();
  // Centroid noise through the least-squares solution: sigma^2 (J^T J)^-1.
  const double sigma = calibration_.centroid_sigma_px;
  const Eigen::Matrix2d cov = sigma * sigma * s.normal_matrix.inverse();
  est.covariance = {cov(0, 0), cov(0, 1), cov(1, 0), cov(1, 1)};
  est.subfov_class = subFovClassOf(calibration_.sensor.subfov, geometry, est.alpha_rad, est.beta_rad);
  // Several spots that disagree beyond their noise: a wrong match or an anomaly.
  if (association->observations.size() > 1 && s.rms_px > 10.0 * sigma + 0.5) {
    est.status = status::kInconsistentSpots;
    return est;
  }
  est.valid = cov.allFinite();
  if (!est.valid) est.status = "degenerate";
  return est;
}

}  // namespace dss
