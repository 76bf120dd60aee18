#include "digital_sun_sensor/ros/pipeline_bench.h"

#include <chrono>
#include <cmath>
#include <fstream>
#include <iostream>
#include <pluginlib/class_list_macros.hpp>
#include <sstream>

#include "digital_sun_sensor/common/file_io.h"
#include "digital_sun_sensor/common/statistics.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/ros/node_params.h"
#include "digital_sun_sensor/ros/node_runner.h"
#include "digital_sun_sensor/sim/dataset_generator.h"

namespace dss {
namespace {

// Malformed variants of a valid image, each one thing wrong.
constexpr int kMalformedKinds = 6;
const char* const kMalformedNames[kMalformedKinds] = {"wrong encoding",     "zero width",     "short buffer",
                                                      "size unlike sensor", "short row step", "oversized width"};

sensor_msgs::Image malformed(const sensor_msgs::Image& good, int kind) {
  sensor_msgs::Image m = good;
  switch (kind) {
    case 0:
      m.encoding = "rgb8";
      break;
    case 1:
      m.width = 0;
      break;
    case 2:
      m.data.resize(m.data.size() / 2);
      break;
    case 3:
      m.width /= 2;
      m.height /= 2;
      m.step /= 2;
      m.data.resize(static_cast<std::size_t>(m.step) * m.height);
      break;
    case 4:
      m.step = m.width / 2;
      break;
    default:
      m.width = 100000;
      m.height = 1;
      m.step = 100000;
      m.data.resize(1000);
  }
  return m;
}

double mean(const std::vector<double>& v) {
  double sum = 0.0;
  for (double x : v) sum += x;
  return v.empty() ? 0.0 : sum / v.size();
}

}  // namespace

PipelineBench::PipelineBench(ros::NodeHandle nh, ros::NodeHandle pnh) : nh_(nh), pnh_(pnh) {
  sensor_param_ = pnh_.param<std::string>("sensor_config", "thesis_sa");
  overrides_ = stringListParam(pnh_, "config_overrides");
  label_ = pnh_.param<std::string>("label", "");
  output_path_ = pnh_.param<std::string>("output", "");
  rate_hz_ = pnh_.param("rate_hz", rate_hz_);
  duration_s_ = pnh_.param("duration_s", duration_s_);
  warmup_s_ = pnh_.param("warmup_s", warmup_s_);
  settle_s_ = pnh_.param("settle_s", settle_s_);
  start_timeout_s_ = pnh_.param("start_timeout_s", start_timeout_s_);
  image_count_ = pnh_.param("images", image_count_);
  malformed_fraction_ = pnh_.param("malformed_fraction", malformed_fraction_);
  clean_tail_s_ = pnh_.param("clean_tail_s", clean_tail_s_);
  if (!(malformed_fraction_ >= 0.0 && malformed_fraction_ <= 1.0))
    throw std::runtime_error("~malformed_fraction must be in [0, 1]");
  if (!(clean_tail_s_ >= 0.0)) throw std::runtime_error("~clean_tail_s must be >= 0");
  seed_ = static_cast<std::uint64_t>(pnh_.param("seed", 7));
  if (!(rate_hz_ > 0.0 && rate_hz_ <= 20000.0)) throw std::runtime_error("~rate_hz must be in (0, 20000]");
  if (!(duration_s_ > 0.0)) throw std::runtime_error("~duration_s must be > 0");
  if (!(warmup_s_ >= 0.0 && settle_s_ >= 0.0)) throw std::runtime_error("~warmup_s and ~settle_s must be >= 0");
  if (image_count_ < 1) throw std::runtime_error("~images must be >= 1");

  image_pub_ = nh_.advertise<sensor_msgs::Image>("image", 100);
  angles_sub_ = nh_.subscribe("angles", 1000, &PipelineBench::onAngles, this, ros::TransportHints().tcpNoDelay());
  diagnostics_sub_ = nh_.subscribe("/diagnostics", 10, &PipelineBench::onDiagnostics, this);
  thread_ = std::thread([this] {
    try {
      run();
    } catch (const std::exception& e) {
      ROS_FATAL("pipeline_bench: %s", e.what());
    }
    ros::requestShutdown();
  });
}

PipelineBench::~PipelineBench() {
  stopping_ = true;
  if (thread_.joinable()) thread_.join();
}

void PipelineBench::run() {
  // Images to replay: rendered once, before the clock starts.
  const SensorConfig config = loadSensorConfig(resolveSensorConfigPath(sensor_param_), overrides_);
  DatasetSpec spec;
  spec.count = static_cast<std::uint64_t>(image_count_);
  spec.seed = seed_;
  std::vector<sensor_msgs::Image> images;
  std::vector<Truth> truths;
  ROS_INFO("pipeline_bench: rendering %d %s images...", image_count_, config.name.c_str());
  DatasetGenerator(config, spec).run([&](const DatasetItem& item) {
    images.push_back(toImageMsg(item.image, std_msgs::Header()));
    images.back().header.frame_id = "sun_sensor_link";
    truths.push_back({item.truth.alpha_rad, item.truth.beta_rad});
  });

  const ros::WallTime wait_until = ros::WallTime::now() + ros::WallDuration(start_timeout_s_);
  while (!stopping_ && (image_pub_.getNumSubscribers() == 0 || angles_sub_.getNumPublishers() == 0)) {
    if (ros::WallTime::now() > wait_until)
      throw std::runtime_error("no estimator subscribed to " + image_pub_.getTopic() + " and publishing " +
                               angles_sub_.getTopic() + " within " + std::to_string(start_timeout_s_) + " s");
    ros::WallDuration(0.05).sleep();
  }

  using Clock = std::chrono::steady_clock;
  const auto period = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / rate_hz_));
  std::uint64_t next_image = 0;
  // Every n-th measured image is malformed (0: none).
  const std::uint64_t malformed_every =
      malformed_fraction_ > 0.0 ? std::max<std::uint64_t>(1, std::llround(1.0 / malformed_fraction_)) : 0;
  // Publishes at the rate for `seconds`; returns how many were published.
  auto publishFor = [&](double seconds, bool measured) {
    const auto end = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(seconds));
    auto next = Clock::now();
    std::uint64_t count = 0;
    while (!stopping_ && ros::ok() && next < end) {
      std::this_thread::sleep_until(next);
      next += period;
      const std::size_t k = next_image++ % images.size();
      const bool bad = measured && malformed_every && next_image % malformed_every == 0;
      const int kind = static_cast<int>((next_image / std::max<std::uint64_t>(malformed_every, 1)) % kMalformedKinds);
      // A fresh message each time: receivers keep theirs.
      auto msg = boost::make_shared<sensor_msgs::Image>(bad ? malformed(images[k], kind) : images[k]);
      msg->header.stamp = ros::Time::now();
      msg->header.seq = static_cast<std::uint32_t>(next_image);
      if (bad) {
        std::lock_guard<std::mutex> lock(mutex_);
        sent_malformed_[msg->header.stamp.toNSec()] = kind;
        ++malformed_published_;
      } else if (measured) {
        std::lock_guard<std::mutex> lock(mutex_);
        sent_[msg->header.stamp.toNSec()] = truths[k];
      }
      image_pub_.publish(msg);
      ++count;
    }
    return count;
  };
  ROS_INFO("pipeline_bench: warm-up %.1f s, then %.1f s at %.0f Hz", warmup_s_, duration_s_, rate_hz_);
  publishFor(warmup_s_, false);
  ros::WallDuration(settle_s_).sleep();
  {
    std::lock_guard<std::mutex> lock(mutex_);
    measuring_ = true;
  }
  const auto t0 = Clock::now();
  const std::uint64_t published = publishFor(duration_s_, true);
  const double elapsed_s = std::chrono::duration<double>(Clock::now() - t0).count();
  ros::WallDuration(settle_s_).sleep();
  if (clean_tail_s_ > 0.0) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      in_tail_ = true;
    }
    ROS_INFO("pipeline_bench: %.1f s of valid images", clean_tail_s_);
    publishFor(clean_tail_s_, false);
  }
  ros::WallDuration(1.2).sleep();  // one more diagnostics period for the memory reading
  const std::string json = report(elapsed_s, published);
  std::cout << json << std::endl;
  if (!output_path_.empty()) writeFileAtomic(output_path_, json + "\n");
}

void PipelineBench::onAngles(const SunAngles::ConstPtr& msg) {
  const ros::Time now = ros::Time::now();
  std::lock_guard<std::mutex> lock(mutex_);
  if (!measuring_) return;
  if (const auto bad = sent_malformed_.find(msg->header.stamp.toNSec()); bad != sent_malformed_.end()) {
    ++malformed_answered_;
    if (!msg->valid && msg->status.rfind(SunAngles::STATUS_BAD_IMAGE, 0) == 0)
      ++malformed_refused_;
    else if (malformed_wrong_answer_.empty())
      malformed_wrong_answer_ = std::string(kMalformedNames[bad->second]) +
                                ": valid=" + std::to_string(static_cast<int>(msg->valid)) + " status '" + msg->status +
                                "'";
    sent_malformed_.erase(bad);
    return;
  }
  const auto it = sent_.find(msg->header.stamp.toNSec());
  if (it == sent_.end()) return;  // a warm-up image, or answered twice
  latency_ms_.push_back((now - msg->header.stamp).toSec() * 1e3);
  ++answered_;
  if (msg->valid) {
    ++valid_;
    abs_error_alpha_deg_.push_back(std::abs(msg->alpha - it->second.alpha_rad) * kDegPerRad);
    abs_error_beta_deg_.push_back(std::abs(msg->beta - it->second.beta_rad) * kDegPerRad);
  }
  sent_.erase(it);
}

void PipelineBench::onDiagnostics(const diagnostic_msgs::DiagnosticArray::ConstPtr& msg) {
  std::lock_guard<std::mutex> lock(mutex_);
  for (const auto& status : msg->status) {
    if (status.name.find("estimator") == std::string::npos) continue;
    if (measuring_ && !in_tail_ && status.level != diagnostic_msgs::DiagnosticStatus::OK) ++diagnostics_not_ok_;
    if (in_tail_) {
      diagnostics_level_after_ = status.level;
      diagnostics_message_after_ = status.message;
    }
    for (const auto& kv : status.values) {
      if (kv.key == "resident memory [MiB]") {
        const double rss = std::atof(kv.value.c_str());
        if (measuring_ && rss_first_mib_ < 0.0) rss_first_mib_ = rss;
        if (measuring_) rss_max_mib_ = std::max(rss_max_mib_, rss);
        rss_last_mib_ = rss;
      } else if (kv.key == "images dropped") {
        estimator_dropped_ = kv.value;
      }
    }
  }
}

std::string PipelineBench::report(double elapsed_s, std::uint64_t published) const {
  std::lock_guard<std::mutex> lock(mutex_);
  const std::uint64_t unanswered = sent_.size();
  std::ostringstream o;
  o.precision(6);
  o << "{\"bench\": \"pipeline\", \"label\": \"" << label_ << "\", \"sensor\": \"" << sensor_param_
    << "\", \"rate_set_hz\": " << rate_hz_ << ", \"duration_s\": " << elapsed_s << ", \"published\": " << published
    << ", \"rate_in_hz\": " << published / elapsed_s << ", \"answered\": " << answered_
    << ", \"rate_out_hz\": " << answered_ / elapsed_s << ", \"dropped\": " << unanswered
    << ", \"drop_fraction\": " << (published ? static_cast<double>(unanswered) / published : 0.0)
    << ", \"latency_p50_ms\": " << percentile(latency_ms_, 0.5)
    << ", \"latency_p99_ms\": " << percentile(latency_ms_, 0.99)
    << ", \"latency_max_ms\": " << percentile(latency_ms_, 1.0)
    << ", \"valid_fraction\": " << (answered_ ? static_cast<double>(valid_) / answered_ : 0.0)
    << ", \"mean_error_alpha_deg\": " << mean(abs_error_alpha_deg_)
    << ", \"mean_error_beta_deg\": " << mean(abs_error_beta_deg_) << ", \"estimator_dropped_total\": \""
    << estimator_dropped_ << "\", \"estimator_rss_start_mib\": " << rss_first_mib_
    << ", \"estimator_rss_max_mib\": " << rss_max_mib_ << ", \"estimator_rss_end_mib\": " << rss_last_mib_;
  if (malformed_fraction_ > 0.0) {
    o << ", \"malformed_published\": " << malformed_published_ << ", \"malformed_answered\": " << malformed_answered_
      << ", \"malformed_refused_bad_image\": " << malformed_refused_ << ", \"malformed_first_wrong_answer\": \""
      << malformed_wrong_answer_ << "\", \"diagnostics_not_ok_reports\": " << diagnostics_not_ok_;
  }
  if (clean_tail_s_ > 0.0)
    o << ", \"diagnostics_level_after\": " << diagnostics_level_after_ << ", \"diagnostics_message_after\": \""
      << diagnostics_message_after_ << "\"";
  o << "}";
  return o.str();
}

// Nodelet front end: put it in the estimator's manager to measure the
// zero-copy pipeline.
class PipelineBenchNodelet : public NodeletFor<PipelineBench> {};

}  // namespace dss

PLUGINLIB_EXPORT_CLASS(dss::PipelineBenchNodelet, nodelet::Nodelet)
