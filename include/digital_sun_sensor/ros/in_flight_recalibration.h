// calibration_node's in-flight recalibration (~recalibration/enabled, off by
// default): reference sun directions (geometry_msgs/Vector3Stamped in any
// frame tf resolves to the image's) are paired with the images of the same
// stamp, the geometric-head model's geometry is refitted from a bounded
// window of pairs (model/unit_recalibration), the result is published on
// unit_geometry, and ~save_unit_model writes the recalibrated unit model
// atomically. The same pairs tell whether the estimates still agree with the
// references within their sigma (estimate/reference_consistency): where not
// (a unit that drifted as a whole), widen() widens each estimate's sigma
// until a refit brings them back.
#pragma once

#include <diagnostic_updater/diagnostic_updater.h>
#include <ros/ros.h>
#include <std_srvs/Trigger.h>

#include <memory>
#include <mutex>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "digital_sun_sensor/common/sun_estimate.h"
#include "digital_sun_sensor/estimate/reference_consistency.h"
#include "digital_sun_sensor/model/unit_recalibration.h"
#include "digital_sun_sensor/ros/sun_direction_input.h"

namespace dss {

class SscnnEstimator;

class InFlightRecalibration {
 public:
  // Reads ~recalibration/* from `pnh`; throws std::runtime_error naming a
  // bad parameter. `estimator` (a geometric-head model) is used under
  // `estimator_mutex`, which the caller also holds while estimating.
  InFlightRecalibration(ros::NodeHandle nh, ros::NodeHandle pnh, SscnnEstimator& estimator, std::mutex& estimator_mutex,
                        std::string model_path);

  // Called with estimator_mutex held, after the batch was estimated: pairs
  // images with references of their stamp and refits when due.
  void offer(const std::vector<cv::Mat>& images, const std::vector<std_msgs::Header>& headers,
             const std::vector<SunEstimate>& estimates);
  // Called with estimator_mutex held, after offer: widens an estimate's
  // sigma by what the references show where they disagree with it (as
  // judged with the batch's pairs, before a refit they may have started).
  void widen(SunEstimate& estimate) const { judged_.widen(estimate); }
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat);

 private:
  bool onSave(std_srvs::Trigger::Request& request, std_srvs::Trigger::Response& response);

  SscnnEstimator& estimator_;
  std::mutex& estimator_mutex_;
  std::string model_path_, output_path_;
  UnitRecalibrator recalibrator_;
  ReferenceConsistency consistency_, judged_;
  std::unique_ptr<SunDirectionInput> references_;
  ros::Publisher geometry_pub_;
  ros::ServiceServer save_service_;

  std::mutex stats_mutex_;  // what diagnose reads
  std::uint64_t refit_failures_ = 0;
  std::size_t pairs_ = 0, refused_ = 0, refits_ = 0;
  double spread_deg_ = 0.0;
  std::string last_refit_;
  std::size_t consistency_pairs_ = 0;
  std::array<double, 2> consistency_normalized_{}, widened_by_deg_{};
};

}  // namespace dss
