#include "digital_sun_sensor/ros/calibration_node.h"

#include <geometry_msgs/TransformStamped.h>
#include <geometry_msgs/Vector3Stamped.h>
#include <ros/package.h>

#include <Eigen/Geometry>
#include <chrono>
#include <fstream>
#include <pluginlib/class_list_macros.hpp>
#include <sstream>
#include <thread>

#include "digital_sun_sensor/common/estimate_status.h"
#include "digital_sun_sensor/common/statistics.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/estimate/estimator_factory.h"
#include "digital_sun_sensor/estimate/screened_estimator.h"
#include "digital_sun_sensor/model/sscnn_estimator.h"
#include "digital_sun_sensor/ros/conversions.h"
#include "digital_sun_sensor/ros/node_params.h"
#include "digital_sun_sensor/ros/node_runner.h"
#include "digital_sun_sensor/sim/geometry.h"
#include "digital_sun_sensor/sparse/threads.h"

namespace dss {
namespace {

constexpr std::size_t kLatencyWindow = 2000;  // recent images kept for the latency percentiles

bool fileExists(const std::string& path) { return std::ifstream(path).good(); }

// "" means the shipped file models/<sensor><suffix> (when it exists), "none"
// means no file; anything else is a path.
std::string resolveModelFile(const std::string& value, const std::string& sensor, const std::string& suffix,
                             bool must_exist) {
  if (value == "none") return "";
  if (!value.empty()) return value;
  const std::string shipped = ros::package::getPath("digital_sun_sensor") + "/models/" + sensor + suffix;
  return (!must_exist || fileExists(shipped)) ? shipped : "";
}

double residentMemoryMiB() {
  std::ifstream status("/proc/self/status");
  for (std::string line; std::getline(status, line);) {
    if (line.rfind("VmRSS:", 0) == 0) return std::stod(line.substr(6)) / 1024.0;  // kB
  }
  return 0.0;
}

}  // namespace

// The updater is named after the private namespace, which is the node's name
// for both the node and the nodelet (whose process is the manager).
CalibrationNode::CalibrationNode(ros::NodeHandle nh, ros::NodeHandle pnh)
    : nh_(nh), pnh_(pnh), updater_(nh, pnh, pnh.getNamespace()) {
  const std::string sensor_param = pnh_.param<std::string>("sensor_config", "thesis_sa");
  const SensorConfig sensor =
      loadSensorConfig(resolveSensorConfigPath(sensor_param), stringListParam(pnh_, "config_overrides"));
  sensor_name_ = sensor.name;
  model_path_ = resolveModelFile(pnh_.param<std::string>("model", ""), sensor.name, ".dssmodel", false);
  calibration_path_ = resolveModelFile(pnh_.param<std::string>("calibration", ""), sensor.name, ".calib.yaml", true);
  default_frame_id_ = pnh_.param<std::string>("frame_id", "sun_sensor_link");
  sun_frame_id_ = pnh_.param<std::string>("sun_frame_id", "sun");
  publish_tf_ = pnh_.param("publish_tf", true);
  const int queue_size = pnh_.param("queue_size", 4), max_batch = pnh_.param("max_batch", 8);
  if (queue_size < 1) throw std::runtime_error("~queue_size must be >= 1");
  if (max_batch < 1) throw std::runtime_error("~max_batch must be >= 1");
  queue_size_ = static_cast<std::size_t>(queue_size);
  max_batch_ = static_cast<std::size_t>(max_batch);
  ScreenOptions screen;
  screen.min_spot_px = pnh_.param("min_spot_px", screen.min_spot_px);
  screen.spike_sigmas = pnh_.param("spike_sigmas", screen.spike_sigmas);
  screen.max_saturated_fraction = pnh_.param("max_saturated_fraction", screen.max_saturated_fraction);
  screen.max_sigma_deg = pnh_.param("max_sigma_deg", screen.max_sigma_deg);
  screen.fov_margin_deg = pnh_.param("fov_margin_deg", screen.fov_margin_deg);
  try {
    screen.validate();
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error(std::string("~") + e.what());
  }
  // Inference per image is fastest single-threaded; the other core is left to
  // the image source (docs/sscnn.md, "Threads").
  sparse::configureThreads(std::max(1, pnh_.param("aten_threads", 1)), std::max(1, pnh_.param("blas_threads", 1)));

  EstimatorOptions estimator_options;
  const std::string symmetry_param = pnh_.param<std::string>("inference_symmetry", "model");
  try {
    estimator_options.mirror_average = mirrorAverageFromName(symmetry_param);
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error(std::string("~inference_symmetry: ") + e.what());
  }
  EstimatorChoice choice = chooseEstimator(model_path_, calibration_path_, sensor, estimator_options);
  auto* sscnn = dynamic_cast<SscnnEstimator*>(choice.estimator.get());  // still owned by the screen below
  if (sscnn) {
    inference_symmetry_ = sscnn->inferenceSymmetry();
    mismatch_threshold_ = sscnn->mismatchThreshold();
    const std::string unit = sscnn->unitCalibration();
    unit_ = unit.empty() ? "nominal design" : unit;
  }
  if (choice.estimator) {
    source_ = choice.estimator->source();
    estimator_ = std::make_unique<ScreenedEstimator>(std::move(choice.estimator), screen);
  }
  is_fallback_ = choice.is_fallback;
  estimator_problem_ = choice.problem;
  if (estimator_ && pnh_.param("warm_up", true)) {
    // Before the first image: a pattern head's first images would otherwise
    // compute its design's diffraction cache (seconds each on thesis_ca).
    const ros::WallTime start = ros::WallTime::now();
    estimator_->warmUp(static_cast<int>(std::max(1u, std::thread::hardware_concurrency())));
    const double took_s = (ros::WallTime::now() - start).toSec();
    if (took_s > 0.5) ROS_INFO("calibration_node: estimator warmed up in %.1f s", took_s);
  }
  if (!estimator_) {
    ROS_ERROR("calibration_node: no estimator: %s. Every image will be answered valid=false (no_estimator).",
              estimator_problem_.c_str());
  } else if (is_fallback_) {
    ROS_WARN("calibration_node: SSCNN not used (%s); falling back to the %s baseline from %s",
             estimator_problem_.c_str(), estimator_->source().c_str(), calibration_path_.c_str());
  } else {
    ROS_INFO("calibration_node: SSCNN model %s for sensor %s (mirror images averaged: %s)%s", model_path_.c_str(),
             sensor_name_.c_str(), inference_symmetry_.c_str(),
             calibration_path_.empty() ? "" : (", fallback calibration " + calibration_path_).c_str());
  }

  if (pnh_.param("recalibration/enabled", false)) {
    if (sscnn && sscnn->hasGeometry())
      recalibration_ = std::make_unique<InFlightRecalibration>(nh_, pnh_, *sscnn, estimator_mutex_, model_path_);
    else
      ROS_ERROR("calibration_node: ~recalibration/enabled, but %s: in-flight recalibration is off",
                sscnn ? "the model has no geometric head" : "no SSCNN model is in use");
  }

  const std::string coarse_topic = pnh_.param<std::string>("coarse_sun/topic", "");
  if (!coarse_topic.empty()) {
    // A coarse sun sensor's direction chooses where a repeating pattern fits
    // two places about equally (thesis_ca); other estimators ignore it.
    const double sigma_deg = pnh_.param("coarse_sun/sigma_deg", 1.0);
    if (!(sigma_deg > 0.0)) throw std::runtime_error("~coarse_sun/sigma_deg must be positive");
    coarse_sigma_rad_ = degToRad(sigma_deg);
    try {
      coarse_sun_ = std::make_unique<SunDirectionInput>(
          nh_, coarse_topic, pnh_.param("coarse_sun/max_stamp_difference_s", 0.05), "coarse sun direction");
    } catch (const std::invalid_argument& e) {
      throw std::runtime_error(std::string("~coarse_sun/max_stamp_difference_s: ") + e.what());
    }
  }

  TrackingOptions tracking;
  tracking.max_rate_deg_s = pnh_.param("tracking/max_rate_deg_s", tracking.max_rate_deg_s);
  tracking.max_age_s = pnh_.param("tracking/max_age_s", tracking.max_age_s);
  try {
    tracking_ = TrackingPrior(tracking);
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error(std::string("~") + e.what());
  }

  angles_pub_ = nh_.advertise<SunAngles>("angles", 10);
  vector_pub_ = nh_.advertise<geometry_msgs::Vector3Stamped>("sun_vector", 10);
  // The subscriber queue is deep and its callback only enqueues, so that
  // overload drops happen in our bounded queue, where they are counted.
  image_sub_ = nh_.subscribe("image", 100, &CalibrationNode::onImage, this, ros::TransportHints().tcpNoDelay());

  updater_.setHardwareID("sun_sensor_estimator/" + sensor_name_);
  updater_.add("estimator", this, &CalibrationNode::diagnose);
  last_diag_time_ = ros::WallTime::now();
  diagnostics_timer_ = nh_.createTimer(ros::Duration(0.2), [this](const ros::TimerEvent&) { updater_.update(); });
  worker_ = std::thread(&CalibrationNode::workerLoop, this);
}

CalibrationNode::~CalibrationNode() {
  {
    std::lock_guard<std::mutex> lock(queue_mutex_);
    stopping_ = true;
  }
  queue_cv_.notify_all();
  if (worker_.joinable()) worker_.join();
}

void CalibrationNode::onImage(const sensor_msgs::Image::ConstPtr& msg) {
  bool dropped = false;
  {
    std::lock_guard<std::mutex> lock(queue_mutex_);
    if (queue_.size() >= queue_size_) {
      queue_.pop_front();  // the newest image is the most useful to attitude control
      dropped = true;
    }
    queue_.push_back(msg);
  }
  queue_cv_.notify_one();
  std::lock_guard<std::mutex> lock(stats_mutex_);
  ++received_;
  if (dropped) ++dropped_;
}

void CalibrationNode::workerLoop() {
  for (;;) {
    std::vector<sensor_msgs::Image::ConstPtr> batch;
    {
      std::unique_lock<std::mutex> lock(queue_mutex_);
      queue_cv_.wait(lock, [this] { return stopping_ || !queue_.empty(); });
      if (stopping_) return;
      while (!queue_.empty() && batch.size() < max_batch_) {
        batch.push_back(queue_.front());
        queue_.pop_front();
      }
    }
    process(batch);
  }
}

void CalibrationNode::process(const std::vector<sensor_msgs::Image::ConstPtr>& batch) {
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<SunEstimate> estimates(batch.size());
  std::vector<cv::Mat> images;
  std::vector<std::size_t> where;
  std::uint64_t priors = 0;  // images given the tracking prior
  for (std::size_t i = 0; i < batch.size(); ++i) {
    try {
      images.push_back(imageFromMsg(*batch[i]));
      where.push_back(i);
    } catch (const std::invalid_argument& e) {
      estimates[i].status = status::withDetail(status::kBadImage, e.what());
    }
  }
  if (!estimator_) {
    for (std::size_t i : where) estimates[i].status = status::kNoEstimator;
  } else if (!images.empty()) {
    std::lock_guard<std::mutex> lock(estimator_mutex_);
    try {
      std::vector<SunEstimate> out;
      if (coarse_sun_ || tracking_.enabled()) {
        // Per image the coarse sun sensor's direction or the tracking prior,
        // whichever is tighter (the images of a batch share the prior from
        // before it).
        CoarseDirections coarse;
        for (std::size_t i : where) {
          std_msgs::Header header = batch[i]->header;
          if (header.frame_id.empty()) header.frame_id = default_frame_id_;
          std::optional<CoarseDirection> direction;
          if (coarse_sun_) {
            if (const auto angles = coarse_sun_->forImage(header))
              direction = CoarseDirection{(*angles)[0], (*angles)[1], coarse_sigma_rad_};
          }
          const auto prior = header.stamp.isZero() ? std::nullopt : tracking_.at(header.stamp.toSec());
          if (prior && (!direction || prior->sigma_rad < direction->sigma_rad)) {
            direction = prior;
            ++priors;
          }
          coarse.push_back(direction);
        }
        out = estimator_->estimateWithCoarseDirections(images, coarse);
      } else {
        out = estimator_->estimate(images);
      }
      for (std::size_t k = 0; k < out.size(); ++k) estimates[where[k]] = std::move(out[k]);
    } catch (const std::exception& e) {
      ROS_ERROR_THROTTLE(5.0, "calibration_node: estimator failed: %s", e.what());
      for (std::size_t i : where) estimates[i].status = status::withDetail(status::kEstimatorError, e.what());
    }
    if (recalibration_) {
      std::vector<std_msgs::Header> headers;
      std::vector<SunEstimate> paired;
      for (std::size_t i : where) {
        headers.push_back(batch[i]->header);
        if (headers.back().frame_id.empty()) headers.back().frame_id = default_frame_id_;
        paired.push_back(estimates[i]);
      }
      // The refit re-reads the images as the estimator read them: hot pixels repaired, specks removed.
      std::vector<cv::Mat> screened;
      for (const cv::Mat& image : images) screened.push_back(estimator_->screenedImage(image));
      try {
        recalibration_->offer(screened, headers, paired);
      } catch (const std::exception& e) {
        ROS_ERROR_THROTTLE(5.0, "calibration_node: recalibration failed: %s", e.what());
      }
      for (std::size_t i : where) recalibration_->widen(estimates[i]);
    }
  }
  // The answers as published, in order, become the tracking prior (images
  // without a stamp carry no time to age it by).
  std::uint64_t contradictions = 0;
  for (std::size_t i = 0; i < batch.size() && tracking_.enabled(); ++i) {
    if (batch[i]->header.stamp.isZero()) continue;
    contradictions += tracking_.update(batch[i]->header.stamp.toSec(), estimates[i]);
  }
  for (std::size_t i = 0; i < batch.size(); ++i) {
    // Encoding, buffer, or a size the sensor config disagrees with.
    if (status::statusCode(estimates[i].status) == status::kBadImage)
      ROS_ERROR_THROTTLE(5.0, "calibration_node: %s", estimates[i].status.c_str());
    publish(batch[i]->header, estimates[i], estimator_ ? source_ : "none");
  }
  const double processing_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  const ros::Time now = ros::Time::now();

  std::lock_guard<std::mutex> lock(stats_mutex_);
  tracking_priors_ += priors;
  tracking_contradictions_ += contradictions;
  for (std::size_t i = 0; i < batch.size(); ++i) {
    const SunEstimate& e = estimates[i];
    ++processed_;
    if (e.valid) {
      ++valid_;
      if (is_fallback_) ++fallback_estimates_;
    } else {
      const std::string reason = status::statusCode(e.status);
      ++invalid_reasons_[reason];
      if (reason == status::kBadImage) {
        ++bad_images_;
        last_bad_image_ = e.status;
      }
    }
    const double latency_ms = (now - batch[i]->header.stamp).toSec() * 1e3;
    if (latency_ms_.size() < kLatencyWindow) {
      latency_ms_.push_back(latency_ms);
      processing_ms_.push_back(processing_ms);
    } else {
      latency_ms_[latency_next_] = latency_ms;
      processing_ms_[latency_next_] = processing_ms;
    }
    latency_next_ = (latency_next_ + 1) % kLatencyWindow;
    if (e.spot_mismatch > 0.0) {
      // Flagged estimates count at their level: the median then tells
      // whether most recent images fit the model's geometry.
      if (spot_mismatch_.size() < kLatencyWindow)
        spot_mismatch_.push_back(e.spot_mismatch);
      else
        spot_mismatch_[mismatch_next_] = e.spot_mismatch;
      mismatch_next_ = (mismatch_next_ + 1) % kLatencyWindow;
    }
  }
}

void CalibrationNode::publish(const std_msgs::Header& image_header, const SunEstimate& e, const std::string& source) {
  std_msgs::Header header = image_header;
  if (header.frame_id.empty()) header.frame_id = default_frame_id_;
  auto angles = boost::make_shared<SunAngles>();
  angles->header = header;
  angles->alpha = e.valid ? e.alpha_rad : 0.0;
  angles->beta = e.valid ? e.beta_rad : 0.0;
  for (int k = 0; k < 4; ++k) angles->covariance[k] = e.valid ? e.covariance[k] : 0.0;
  angles->subfov_class = e.valid ? e.subfov_class : SunAngles::SUBFOV_UNKNOWN;
  angles->valid = e.valid;
  angles->source = source;
  angles->status = e.status;
  angles_pub_.publish(angles);
  if (!e.valid) return;

  const auto vector =
      boost::make_shared<geometry_msgs::Vector3Stamped>(toSunVectorMsg(e.alpha_rad, e.beta_rad, header));
  vector_pub_.publish(vector);

  if (publish_tf_) {
    const Eigen::Vector3d sun(vector->vector.x, vector->vector.y, vector->vector.z);
    // The `sun` frame's +x axis points at the sun (docs/design.md, "Frames and angles").
    const Eigen::Quaterniond q = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitX(), sun);
    geometry_msgs::TransformStamped tf;
    tf.header = header;
    tf.child_frame_id = sun_frame_id_;
    tf.transform.rotation.w = q.w();
    tf.transform.rotation.x = q.x();
    tf.transform.rotation.y = q.y();
    tf.transform.rotation.z = q.z();
    tf_broadcaster_.sendTransform(tf);
  }
}

void CalibrationNode::diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat) {
  std::lock_guard<std::mutex> lock(stats_mutex_);
  const ros::WallTime now = ros::WallTime::now();
  const double window_s = (now - last_diag_time_).toSec();
  const double input_hz = window_s > 0.0 ? (received_ - received_at_last_diag_) / window_s : 0.0;
  last_diag_time_ = now;
  received_at_last_diag_ = received_;
  const std::uint64_t processed_now = processed_ - processed_at_last_diag_;
  const std::uint64_t bad_now = bad_images_ - bad_images_at_last_diag_;
  processed_at_last_diag_ = processed_;
  bad_images_at_last_diag_ = bad_images_;
  const std::uint64_t contradictions_now = tracking_contradictions_ - contradictions_at_last_diag_;
  contradictions_at_last_diag_ = tracking_contradictions_;
  const std::string bad_summary = std::to_string(bad_now) + " of " + std::to_string(processed_now) +
                                  " images since the last report were bad (latest: " + last_bad_image_ + ")";

  if (!estimator_) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::ERROR, "no estimator: " + estimator_problem_);
  } else if (bad_now > 0 && bad_now == processed_now) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::ERROR, bad_summary);
  } else if (is_fallback_) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, "centroid fallback: " + estimator_problem_);
  } else if (received_ == 0) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::OK, "waiting for images");
  } else if (mismatch_threshold_ > 0.0 && percentile(spot_mismatch_, 0.5) > mismatch_threshold_) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN,
                 "model_mismatch: most recent spots do not fit the model's geometry (an uncalibrated or drifted "
                 "unit): calibrate the unit (dss calibrate-unit)");
  } else if (bad_now > 0) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, bad_summary);
  } else if (contradictions_now > 0) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN,
                 std::to_string(contradictions_now) +
                     " answers since the last report lay far from the tracking prior: is ~tracking/max_rate_deg_s "
                     "below the spacecraft's rate, or are the images not one sequence?");
  } else {
    stat.summary(diagnostic_msgs::DiagnosticStatus::OK, "estimating");
  }
  stat.add("sensor", sensor_name_);
  stat.add("source", estimator_ ? source_ : "none");
  stat.add("model", model_path_.empty() ? "none" : model_path_);
  stat.add("inference symmetry", inference_symmetry_);
  stat.add("unit calibration", unit_);
  stat.add("calibration (fallback)", calibration_path_.empty() ? "none" : calibration_path_);
  stat.add("input rate [Hz]", input_hz);
  stat.add("images received", received_);
  stat.add("images dropped", dropped_);
  stat.add("bad images", bad_images_);
  stat.add("images processed", processed_);
  stat.add("valid rate [%]", processed_ ? 100.0 * valid_ / processed_ : 0.0);
  stat.add("fallback estimates", fallback_estimates_);
  stat.add("latency p50 [ms]", percentile(latency_ms_, 0.5));
  stat.add("latency p99 [ms]", percentile(latency_ms_, 0.99));
  stat.add("processing p50 [ms]", percentile(processing_ms_, 0.5));
  if (!spot_mismatch_.empty()) {
    stat.add("spot mismatch p50", percentile(spot_mismatch_, 0.5));
    stat.add("spot mismatch threshold", mismatch_threshold_);
  }
  std::ostringstream reasons;
  for (const auto& [reason, count] : invalid_reasons_)
    reasons << (reasons.tellp() ? ", " : "") << reason << ": " << count;
  stat.add("invalid reasons", reasons.str());
  stat.add("resident memory [MiB]", residentMemoryMiB());
  if (coarse_sun_) {
    const SunDirectionInput::Counts c = coarse_sun_->counts();
    stat.add("coarse sun directions received", c.received);
    stat.add("images with a coarse sun direction", c.paired);
    stat.add("images without one", c.unpaired_images + c.unresolved_frames + c.behind_sensor);
  }
  if (tracking_.enabled()) {
    stat.add("images with the tracking prior", tracking_priors_);
    stat.add("answers contradicting the tracking prior", tracking_contradictions_);
  }
  if (recalibration_) recalibration_->diagnose(stat);
}

// Nodelet front end: same class, same parameters. Images from a simulator
// nodelet in the same manager arrive without serialization.
class CalibrationNodelet : public NodeletFor<CalibrationNode> {};

}  // namespace dss

PLUGINLIB_EXPORT_CLASS(dss::CalibrationNodelet, nodelet::Nodelet)
