// pipeline_bench: load benchmark of the estimator (calibration_node or its
// nodelet). Pre-renders a set of images with truth, then publishes them on
// `image` at a fixed rate, stamped at publish time, and listens to `angles`:
// the latency is the angles' arrival time minus the image stamp, a drop is an
// image that got no angles. Prints one JSON line (and writes it to ~output)
// and shuts ROS down. With ~malformed_fraction, that share of the measured
// images is replaced by malformed ones (wrong encoding, zero or oversized
// width, short buffer, wrong size, short row step), each of which must be
// answered valid=false with status bad_image; ~clean_tail_s of valid images
// follow, after which the estimator's diagnostics must be back to OK. Used by both the node executable and the nodelet,
// so that the nodelet pipeline is measured without serialization.
#pragma once

#include <diagnostic_msgs/DiagnosticArray.h>
#include <ros/ros.h>
#include <sensor_msgs/Image.h>

#include <atomic>
#include <map>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "digital_sun_sensor/ros/conversions.h"

namespace dss {

class PipelineBench {
 public:
  // Throws std::runtime_error naming a bad parameter.
  PipelineBench(ros::NodeHandle nh, ros::NodeHandle pnh);
  ~PipelineBench();

 private:
  struct Truth {
    double alpha_rad, beta_rad;
  };
  void run();
  void onAngles(const SunAngles::ConstPtr& msg);
  void onDiagnostics(const diagnostic_msgs::DiagnosticArray::ConstPtr& msg);
  std::string report(double elapsed_s, std::uint64_t published) const;

  ros::NodeHandle nh_, pnh_;
  std::string sensor_param_, label_, output_path_;
  std::vector<std::string> overrides_;
  double rate_hz_ = 100.0, duration_s_ = 10.0, warmup_s_ = 1.0, settle_s_ = 1.0, start_timeout_s_ = 120.0;
  int image_count_ = 100;
  double malformed_fraction_ = 0.0, clean_tail_s_ = 0.0;
  std::uint64_t seed_ = 7;

  ros::Publisher image_pub_;
  ros::Subscriber angles_sub_, diagnostics_sub_;
  std::thread thread_;
  std::atomic<bool> stopping_{false};

  mutable std::mutex mutex_;
  bool measuring_ = false;
  std::map<std::uint64_t, Truth> sent_;          // stamp [ns] -> truth of the measured images
  std::map<std::uint64_t, int> sent_malformed_;  // stamp [ns] -> kind of the measured malformed images
  std::uint64_t malformed_published_ = 0, malformed_answered_ = 0, malformed_refused_ = 0;
  std::string malformed_wrong_answer_;  // the first malformed image answered otherwise
  bool in_tail_ = false;
  std::uint64_t diagnostics_not_ok_ = 0;  // estimator reports at WARN or ERROR while measuring
  int diagnostics_level_after_ = -1;      // the estimator's last level, after the clean tail
  std::string diagnostics_message_after_;
  std::vector<double> latency_ms_, abs_error_alpha_deg_, abs_error_beta_deg_;
  std::uint64_t answered_ = 0, valid_ = 0;
  double rss_first_mib_ = -1.0, rss_max_mib_ = 0.0, rss_last_mib_ = 0.0;
  std::string estimator_dropped_ = "?";
};

}  // namespace dss
