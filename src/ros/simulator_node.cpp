#include "digital_sun_sensor/ros/simulator_node.h"

#include <Eigen/Geometry>
#include <chrono>
#include <cmath>
#include <pluginlib/class_list_macros.hpp>
#include <stdexcept>

#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/ros/conversions.h"
#include "digital_sun_sensor/ros/node_params.h"
#include "digital_sun_sensor/ros/node_runner.h"
#include "digital_sun_sensor/sim/geometry.h"
#include "digital_sun_sensor/sim/spot_cache.h"

namespace dss {
namespace {

// Triangle wave in [-1, 1] with period 4.
double triangle(double x) {
  const double m = std::fmod(std::fmod(x + 1.0, 4.0) + 4.0, 4.0);
  return m < 2.0 ? m - 1.0 : 3.0 - m;
}

}  // namespace

// The updater is named after the private namespace, which is the node's name
// for both the node and the nodelet (whose process is the manager).
SimulatorNode::SimulatorNode(ros::NodeHandle nh, ros::NodeHandle pnh)
    : nh_(nh), pnh_(pnh), updater_(nh, pnh, pnh.getNamespace()) {
  const std::string sensor = pnh_.param<std::string>("sensor_config", "thesis_sa");
  std::vector<std::string> overrides = pnh_.param<std::vector<std::string>>("config_overrides", {});
  SensorConfig config = loadSensorConfig(resolveSensorConfigPath(sensor), overrides);

  rate_hz_ = pnh_.param("rate_hz", 10.0);
  if (!(rate_hz_ > 0.0 && rate_hz_ <= 10000.0)) throw std::runtime_error("~rate_hz must be in (0, 10000]");
  frame_id_ = pnh_.param<std::string>("frame_id", "sun_sensor_link");
  body_frame_ = pnh_.param<std::string>("body_frame", "base_link");
  profile_ = pnh_.param<std::string>("profile", "slew");
  if (profile_ != "fixed" && profile_ != "slew" && profile_ != "raster" && profile_ != "random") {
    throw std::runtime_error("~profile must be fixed, slew, raster or random (got '" + profile_ + "')");
  }
  attitude_timeout_s_ = pnh_.param("attitude_timeout_s", 1.0);
  std::vector<double> sun = pnh_.param<std::vector<double>>("sun_direction_inertial", {1.0, 0.0, 0.0});
  if (sun.size() != 3 || Eigen::Vector3d(sun[0], sun[1], sun[2]).norm() < 1e-9) {
    throw std::runtime_error("~sun_direction_inertial must be a non-zero [x, y, z]");
  }
  sun_inertial_ = Eigen::Vector3d(sun[0], sun[1], sun[2]).normalized();
  fixed_alpha_rad_ = pnh_.param("fixed_alpha_deg", 1.0) * kRadPerDeg;
  fixed_beta_rad_ = pnh_.param("fixed_beta_deg", -0.5) * kRadPerDeg;
  slew_rate_rad_s_ = pnh_.param("slew_rate_deg_s", 0.5) * kRadPerDeg;
  slew_heading_rad_ = pnh_.param("slew_heading_deg", 30.0) * kRadPerDeg;
  raster_step_rad_ = pnh_.param("raster_step_deg", 0.5) * kRadPerDeg;
  if (!(raster_step_rad_ > 0.0)) throw std::runtime_error("~raster_step_deg must be > 0");
  seed_ = static_cast<std::uint64_t>(pnh_.param("seed", 1));
  publish_spots_ = pnh_.param("publish_spots", true);
  // The process's whole diffraction cache (a nodelet manager shares it).
  const int cache_mb = pnh_.param("diffraction_cache_mb", 0);
  if (cache_mb < 0) throw std::runtime_error("~diffraction_cache_mb must be >= 0 (0: 40 % of the machine's memory)");
  if (cache_mb > 0) SpotCache::setMemoryLimitBytes(static_cast<std::size_t>(cache_mb) << 20);
  // One sensor drawn from the config (its as-built sigmas decide the errors).
  renderer_ = std::make_unique<Renderer>(SensorInstance::draw(config, seed_));

  if (pnh_.param("warm_up", true)) {
    // Diffraction spots for the whole FOV before the first frame, so that the
    // rate holds from the start (otherwise nodes are computed on first use).
    const int threads = std::max(1, pnh_.param("warm_up_threads", 2));
    ROS_INFO("simulator_node: computing diffraction spots over the field of view (%d threads)...", threads);
    const auto t0 = std::chrono::steady_clock::now();
    renderer_->warmUp(threads, [](std::size_t done, std::size_t total) {
      if (done % 25 == 0 || done == total) ROS_INFO("simulator_node: diffraction spots %zu/%zu", done, total);
    });
    ROS_INFO("simulator_node: diffraction cache ready in %.1f s",
             std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  }

  image_pub_ = nh_.advertise<sensor_msgs::Image>("image", 5);
  truth_pub_ = nh_.advertise<SunAngles>("truth", 5);
  if (publish_spots_) spots_pub_ = nh_.advertise<SpotCentres>("truth_spots", 5);
  attitude_sub_ = nh_.subscribe("attitude", 5, &SimulatorNode::onAttitude, this);
  tf_listener_ = std::make_unique<tf2_ros::TransformListener>(tf_buffer_);

  updater_.setHardwareID("sun_sensor_simulator/" + config.name);
  min_rate_hz_ = max_rate_hz_ = rate_hz_;
  rate_status_ = std::make_unique<diagnostic_updater::FrequencyStatus>(
      diagnostic_updater::FrequencyStatusParam(&min_rate_hz_, &max_rate_hz_, 0.1, 10));
  updater_.add(*rate_status_);
  updater_.add("simulator", this, &SimulatorNode::diagnose);

  start_ = ros::Time::now();
  timer_ = nh_.createTimer(ros::Duration(1.0 / rate_hz_), &SimulatorNode::onTimer, this);
  ROS_INFO("simulator_node: %s at %.1f Hz, profile '%s' until an attitude arrives on %s", config.name.c_str(), rate_hz_,
           profile_.c_str(), attitude_sub_.getTopic().c_str());
}

void SimulatorNode::onAttitude(const geometry_msgs::QuaternionStamped::ConstPtr& msg) {
  const auto& q = msg->quaternion;
  const double norm = std::sqrt(q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z);
  if (!std::isfinite(norm) || std::abs(norm - 1.0) > 1e-3) {
    ROS_WARN_THROTTLE(5.0, "simulator_node: ignoring attitude with quaternion norm %.6f (must be unit)", norm);
    return;
  }
  std::lock_guard<std::mutex> lock(attitude_mutex_);
  last_attitude_ = msg;
}

bool SimulatorNode::attitudeSun(Eigen::Vector3d* sun_sensor) {
  geometry_msgs::QuaternionStamped::ConstPtr att;
  {
    std::lock_guard<std::mutex> lock(attitude_mutex_);
    att = last_attitude_;
  }
  if (!att || (ros::Time::now() - att->header.stamp).toSec() > attitude_timeout_s_) return false;
  // q rotates body vectors into the inertial frame: s_body = q^-1 s_inertial.
  const Eigen::Quaterniond q(att->quaternion.w, att->quaternion.x, att->quaternion.y, att->quaternion.z);
  const Eigen::Vector3d sun_body = q.inverse() * sun_inertial_;
  // Mounting: rotation taking body vectors into the sensor frame.
  try {
    const auto tf = tf_buffer_.lookupTransform(frame_id_, body_frame_, ros::Time(0));
    const auto& r = tf.transform.rotation;
    *sun_sensor = Eigen::Quaterniond(r.w, r.x, r.y, r.z).normalized() * sun_body;
    last_warning_.clear();
  } catch (const tf2::TransformException& e) {
    last_warning_ = std::string("no mounting transform ") + body_frame_ + " -> " + frame_id_ + ": " + e.what();
    ROS_WARN_THROTTLE(5.0, "simulator_node: %s; using identity", last_warning_.c_str());
    *sun_sensor = sun_body;
  }
  return true;
}

Eigen::Vector3d SimulatorNode::profileSun(double t_s) {
  const auto& fov = renderer_->config().fov;
  const double a_max = fov.alpha_max_deg * kRadPerDeg, b_max = fov.beta_max_deg * kRadPerDeg;
  if (profile_ == "fixed") return sunVectorFromAngles(fixed_alpha_rad_, fixed_beta_rad_);
  if (profile_ == "slew") {
    // Constant-rate slew, reflecting at the FOV edges.
    const double d = slew_rate_rad_s_ * t_s;
    return sunVectorFromAngles(a_max * triangle(d * std::cos(slew_heading_rad_) / a_max),
                               b_max * triangle(d * std::sin(slew_heading_rad_) / b_max));
  }
  if (profile_ == "raster") {
    const int n_a = std::max(1, static_cast<int>(std::floor(2.0 * a_max / raster_step_rad_)) + 1);
    const int n_b = std::max(1, static_cast<int>(std::floor(2.0 * b_max / raster_step_rad_)) + 1);
    const std::uint64_t k = frame_count_ % static_cast<std::uint64_t>(n_a * n_b);
    return sunVectorFromAngles(-a_max + (k % n_a) * raster_step_rad_, -b_max + (k / n_a) * raster_step_rad_);
  }
  Rng rng(deriveSeed(seed_, 0x9A0F11E + frame_count_));
  const double alpha = rng.uniform(-a_max, a_max);
  return sunVectorFromAngles(alpha, rng.uniform(-b_max, b_max));
}

void SimulatorNode::onTimer(const ros::TimerEvent&) {
  const ros::Time stamp = ros::Time::now();
  Eigen::Vector3d sun;
  last_from_attitude_ = attitudeSun(&sun);
  if (!last_from_attitude_) sun = profileSun((stamp - start_).toSec());

  const auto t0 = std::chrono::steady_clock::now();
  ImageTruth truth;
  cv::Mat image;
  try {
    image = renderer_->render(sun, deriveSeed(seed_, frame_count_), &truth);
  } catch (const std::exception& e) {
    ROS_ERROR_THROTTLE(5.0, "simulator_node: render failed: %s", e.what());
    return;
  }
  last_render_ms_ = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();

  std_msgs::Header header;
  header.stamp = stamp;
  header.frame_id = frame_id_;
  header.seq = static_cast<std::uint32_t>(frame_count_);
  // Shared pointers: a nodelet in the same manager receives them without a copy.
  image_pub_.publish(boost::make_shared<sensor_msgs::Image>(toImageMsg(image, header)));
  const auto truth_msg = boost::make_shared<SunAngles>(toTruthMsg(truth, renderer_->config(), header));
  last_in_fov_ = truth_msg->valid;
  truth_pub_.publish(truth_msg);
  if (publish_spots_) spots_pub_.publish(toSpotsMsg(truth, header));
  ++frame_count_;
  rate_status_->tick();
  updater_.update();
}

void SimulatorNode::diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat) {
  if (!last_warning_.empty()) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, last_warning_);
  } else if (!last_in_fov_) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::OK, "sun outside the field of view");
  } else {
    stat.summary(diagnostic_msgs::DiagnosticStatus::OK, "rendering");
  }
  stat.add("sensor", renderer_->config().name);
  stat.add("attitude source", last_from_attitude_ ? std::string("/attitude topic") : "profile " + profile_);
  stat.add("render time [ms]", last_render_ms_);
  stat.add("frames published", frame_count_);
  const SpotCache& cache = renderer_->spotCache();
  const std::size_t dropped = cache.nodesDropped();
  // Spots dropped since the last report: renders that pay for diffraction again.
  if (dropped > dropped_at_last_diagnosis_)
    stat.mergeSummary(diagnostic_msgs::DiagnosticStatus::WARN,
                      "diffraction cache at its memory cap: spots computed again (~diffraction_cache_mb)");
  dropped_at_last_diagnosis_ = dropped;
  stat.add("diffraction cache nodes", cache.nodesHeld());
  stat.add("diffraction cache [MB]", cache.bytesHeld() >> 20);
  stat.add("diffraction nodes dropped for memory", dropped);
}

// Nodelet front end: same class, same parameters.
class SimulatorNodelet : public NodeletFor<SimulatorNode> {};

}  // namespace dss

PLUGINLIB_EXPORT_CLASS(dss::SimulatorNodelet, nodelet::Nodelet)
