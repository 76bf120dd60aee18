// The conventional estimator: spot extraction -> association -> least-squares
// sun angles through the calibrated geometry -> residual polynomial, with a
// covariance from the centroid noise seen during calibration.
#pragma once

#include "digital_sun_sensor/baseline/association.h"
#include "digital_sun_sensor/baseline/calibration.h"
#include "digital_sun_sensor/common/sun_estimate.h"
#include "digital_sun_sensor/model/input_spec.h"

namespace dss {

class CentroidEstimator : public SunEstimator {
 public:
  explicit CentroidEstimator(Calibration calibration);

  std::string source() const override { return "centroid"; }
  const SensorConfig& sensor() const override { return calibration_.sensor; }
  std::vector<SunEstimate> estimate(const std::vector<cv::Mat>& images) override;

  SunEstimate estimateOne(const cv::Mat& image, std::vector<DetectedSpot>* spots = nullptr) const;
  const Calibration& calibration() const { return calibration_; }

 private:
  Calibration calibration_;
  InputSpec input_;  // image size and encoding checks
  AssociationOptions association_;
};

}  // namespace dss
