// error_monitor: the live view of the pipeline README's main command shows.
// Pairs /sun_sensor/angles with /sun_sensor/truth by stamp and prints, every
// ~print_period_s, the latest estimate beside the truth, its error and
// predicted 1-sigma, and the mean absolute error and valid rate since the
// last line. Also publishes the latest error as ~error (SunAngles, source
// "error": alpha/beta hold estimate - truth).
#include <digital_sun_sensor/SunAngles.h>
#include <ros/ros.h>

#include <cmath>
#include <cstdio>
#include <map>

#include "digital_sun_sensor/common/units.h"

using dss::kDegPerRad;

namespace {

using digital_sun_sensor::SunAngles;

class ErrorMonitor {
 public:
  ErrorMonitor(ros::NodeHandle nh, ros::NodeHandle pnh) {
    error_pub_ = pnh.advertise<SunAngles>("error", 10);
    truth_sub_ = nh.subscribe("truth", 50, &ErrorMonitor::onTruth, this);
    angles_sub_ = nh.subscribe("angles", 50, &ErrorMonitor::onAngles, this);
    timer_ = nh.createWallTimer(ros::WallDuration(pnh.param("print_period_s", 1.0)), &ErrorMonitor::print, this);
  }

 private:
  void onTruth(const SunAngles::ConstPtr& msg) {
    truths_[msg->header.stamp.toNSec()] = msg;
    while (truths_.size() > 1000) truths_.erase(truths_.begin());
    tryMatch();
  }
  void onAngles(const SunAngles::ConstPtr& msg) {
    estimates_[msg->header.stamp.toNSec()] = msg;
    while (estimates_.size() > 1000) estimates_.erase(estimates_.begin());
    tryMatch();
  }
  // Either message may arrive first.
  void tryMatch() {
    for (auto it = estimates_.begin(); it != estimates_.end();) {
      const auto truth = truths_.find(it->first);
      if (truth == truths_.end()) {
        ++it;
        continue;
      }
      account(*it->second, *truth->second);
      truths_.erase(truth);
      it = estimates_.erase(it);
    }
  }
  void account(const SunAngles& est, const SunAngles& truth) {
    ++count_;
    last_est_ = est;
    last_truth_ = truth;
    if (!est.valid) return;
    ++valid_;
    const double da = (est.alpha - truth.alpha) * kDegPerRad, db = (est.beta - truth.beta) * kDegPerRad;
    sum_abs_a_ += std::abs(da);
    sum_abs_b_ += std::abs(db);
    SunAngles err = est;
    err.alpha = est.alpha - truth.alpha;
    err.beta = est.beta - truth.beta;
    err.source = "error";
    error_pub_.publish(err);
  }
  void print(const ros::WallTimerEvent&) {
    if (count_ == 0) {
      // Once, and again only when estimates stop arriving.
      if (!waiting_) std::printf("error_monitor: waiting for matching /sun_sensor/angles and /sun_sensor/truth...\n");
      waiting_ = true;
    } else if (!last_est_.valid) {
      std::printf("[%s] invalid (%s) | truth a %+.5f b %+.5f deg | %lu images, %.0f%% valid\n",
                  last_est_.source.c_str(), last_est_.status.c_str(), last_truth_.alpha * kDegPerRad,
                  last_truth_.beta * kDegPerRad, count_, 100.0 * valid_ / count_);
    } else {
      const double da = (last_est_.alpha - last_truth_.alpha) * kDegPerRad,
                   db = (last_est_.beta - last_truth_.beta) * kDegPerRad;
      std::printf(
          "[%s] a est %+.5f true %+.5f err %+.5f (1s %.5f) | b est %+.5f true %+.5f err %+.5f (1s %.5f) deg | "
          "%lu images: mean |err| %.5f / %.5f deg, %.0f%% valid\n",
          last_est_.source.c_str(), last_est_.alpha * kDegPerRad, last_truth_.alpha * kDegPerRad, da,
          std::sqrt(last_est_.covariance[0]) * kDegPerRad, last_est_.beta * kDegPerRad, last_truth_.beta * kDegPerRad,
          db, std::sqrt(last_est_.covariance[3]) * kDegPerRad, count_, valid_ ? sum_abs_a_ / valid_ : 0.0,
          valid_ ? sum_abs_b_ / valid_ : 0.0, 100.0 * valid_ / count_);
    }
    if (count_ > 0) waiting_ = false;
    std::fflush(stdout);
    count_ = valid_ = 0;
    sum_abs_a_ = sum_abs_b_ = 0.0;
  }

  ros::Publisher error_pub_;
  ros::Subscriber truth_sub_, angles_sub_;
  ros::WallTimer timer_;
  std::map<std::uint64_t, SunAngles::ConstPtr> truths_, estimates_;
  SunAngles last_est_, last_truth_;
  unsigned long count_ = 0, valid_ = 0;
  bool waiting_ = false;
  double sum_abs_a_ = 0.0, sum_abs_b_ = 0.0;
};

}  // namespace

int main(int argc, char** argv) {
  ros::init(argc, argv, "error_monitor");
  ErrorMonitor monitor(ros::NodeHandle(), ros::NodeHandle("~"));
  ros::spin();
  return 0;
}
