// calibration_node: the estimator an ADCS stack subscribes to. Runs the SSCNN
// (or, when the model is missing or does not load, the centroid baseline) on
// each /sun_sensor/image and publishes /sun_sensor/angles, /sun_sensor/sun_vector
// and the tf sun_sensor_link -> sun, stamped like the image. Images are queued
// in a bounded queue and processed on a worker thread, so that a burst never
// grows memory: the oldest waiting image is dropped and counted. Used by both
// the node executable and the nodelet.
#pragma once

#include <diagnostic_updater/diagnostic_updater.h>
#include <ros/ros.h>
#include <sensor_msgs/Image.h>
#include <tf2_ros/transform_broadcaster.h>

#include <atomic>
#include <condition_variable>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "digital_sun_sensor/common/sun_estimate.h"
#include "digital_sun_sensor/estimate/screened_estimator.h"
#include "digital_sun_sensor/estimate/tracking_prior.h"
#include "digital_sun_sensor/ros/in_flight_recalibration.h"
#include "digital_sun_sensor/ros/sun_direction_input.h"

namespace dss {

class CalibrationNode {
 public:
  // Reads parameters from `pnh`; throws std::runtime_error naming the bad
  // parameter or sensor config. A missing or bad model file is not an error:
  // the node falls back (or publishes valid = false) and says so.
  CalibrationNode(ros::NodeHandle nh, ros::NodeHandle pnh);
  ~CalibrationNode();

 private:
  void onImage(const sensor_msgs::Image::ConstPtr& msg);
  void workerLoop();
  void process(const std::vector<sensor_msgs::Image::ConstPtr>& batch);
  void publish(const std_msgs::Header& header, const SunEstimate& estimate, const std::string& source);
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat);

  ros::NodeHandle nh_, pnh_;
  std::unique_ptr<ScreenedEstimator> estimator_;  // null when neither model nor calibration could be used
  // Held while estimating and while recalibration touches the model.
  std::mutex estimator_mutex_;
  std::unique_ptr<InFlightRecalibration> recalibration_;  // ~recalibration/enabled
  std::unique_ptr<SunDirectionInput> coarse_sun_;         // ~coarse_sun/topic
  double coarse_sigma_rad_ = 0.0;
  // ~tracking: the last answer as the next images' coarse direction (its
  // answers: the worker thread only; its options: fixed before it starts).
  TrackingPrior tracking_;
  std::string source_, estimator_problem_, model_path_, calibration_path_;
  std::string inference_symmetry_ = "none";  // of the SSCNN in use
  double mismatch_threshold_ = 0.0;          // its model_mismatch threshold (0: none)
  std::string unit_ = "none";                // its unit calibration's data, or "nominal design"
  bool is_fallback_ = false;
  std::string sensor_name_, default_frame_id_, sun_frame_id_;
  bool publish_tf_ = true;
  std::size_t queue_size_ = 4, max_batch_ = 8;

  ros::Publisher angles_pub_, vector_pub_;
  ros::Subscriber image_sub_;
  tf2_ros::TransformBroadcaster tf_broadcaster_;
  diagnostic_updater::Updater updater_;
  ros::Timer diagnostics_timer_;

  // Bounded queue between the subscriber callback and the worker.
  std::mutex queue_mutex_;
  std::condition_variable queue_cv_;
  std::deque<sensor_msgs::Image::ConstPtr> queue_;
  bool stopping_ = false;
  std::thread worker_;

  // Counters and recent latencies, for diagnostics.
  std::mutex stats_mutex_;
  std::uint64_t received_ = 0, dropped_ = 0, processed_ = 0, valid_ = 0, fallback_estimates_ = 0;
  std::uint64_t bad_images_ = 0;
  std::map<std::string, std::uint64_t> invalid_reasons_;
  std::vector<double> latency_ms_;     // image stamp -> publish, ring buffer
  std::vector<double> processing_ms_;  // dequeue -> publish, ring buffer
  std::size_t latency_next_ = 0;
  // Recent spot mismatch (geometric-head models; 0 where not measured) and
  // whether the estimate was flagged model_mismatch, ring buffers.
  std::vector<double> spot_mismatch_;
  std::size_t mismatch_next_ = 0;
  std::uint64_t received_at_last_diag_ = 0;
  // Bad images since the last diagnostics period: WARN while they come, OK after.
  std::uint64_t processed_at_last_diag_ = 0, bad_images_at_last_diag_ = 0;
  std::string last_bad_image_;
  // Images given the tracking prior as their coarse direction, and valid
  // answers far from it (a rate bound the motion breaks).
  std::uint64_t tracking_priors_ = 0, tracking_contradictions_ = 0, contradictions_at_last_diag_ = 0;
  ros::WallTime last_diag_time_;
};

}  // namespace dss
