#include "digital_sun_sensor/ros/in_flight_recalibration.h"

#include <digital_sun_sensor/UnitGeometry.h>
#include <yaml-cpp/yaml.h>

#include <cmath>
#include <sstream>

#include "digital_sun_sensor/common/estimate_status.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/model/sscnn_estimator.h"

namespace dss {
namespace {

std::size_t countParam(const ros::NodeHandle& pnh, const std::string& name, std::size_t fallback) {
  const int value = pnh.param(name, static_cast<int>(fallback));
  if (value < 1) throw std::runtime_error("~" + name + " must be at least 1");
  return static_cast<std::size_t>(value);
}

RecalibrationOptions optionsFrom(const ros::NodeHandle& pnh) {
  RecalibrationOptions o;
  o.window = countParam(pnh, "recalibration/window", o.window);
  o.min_pairs = countParam(pnh, "recalibration/min_pairs", o.min_pairs);
  o.refit_every = countParam(pnh, "recalibration/refit_every", o.refit_every);
  o.min_spread_deg = pnh.param("recalibration/min_spread_deg", o.min_spread_deg);
  o.max_disagreement_deg = pnh.param("recalibration/max_disagreement_deg", o.max_disagreement_deg);
  try {
    o.validate();
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error(std::string("~") + e.what());
  }
  return o;
}

ConsistencyOptions consistencyFrom(const ros::NodeHandle& pnh) {
  ConsistencyOptions o;
  o.window = countParam(pnh, "recalibration/consistency_window", o.window);
  o.min_pairs = countParam(pnh, "recalibration/consistency_min_pairs", o.min_pairs);
  o.reference_sigma_deg = pnh.param("recalibration/reference_sigma_deg", o.reference_sigma_deg);
  o.max_normalized = pnh.param("recalibration/consistency_max_normalized", o.max_normalized);
  try {
    o.validate();
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error(std::string("~recalibration/") + e.what());
  }
  return o;
}

}  // namespace

InFlightRecalibration::InFlightRecalibration(ros::NodeHandle nh, ros::NodeHandle pnh, SscnnEstimator& estimator,
                                             std::mutex& estimator_mutex, std::string model_path)
    : estimator_(estimator),
      estimator_mutex_(estimator_mutex),
      model_path_(std::move(model_path)),
      recalibrator_(optionsFrom(pnh)),
      consistency_(consistencyFrom(pnh)),
      judged_(consistency_) {
  if (!estimator_.hasGeometry())
    throw std::runtime_error("~recalibration/enabled: the model " + model_path_ +
                             " has no geometric head, so no geometry to recalibrate");
  const double max_stamp_difference_s = pnh.param("recalibration/max_stamp_difference_s", 0.02);
  if (!(max_stamp_difference_s >= 0.0)) throw std::runtime_error("~recalibration/max_stamp_difference_s must be >= 0");
  output_path_ = pnh.param<std::string>("recalibration/output", "");
  references_ = std::make_unique<SunDirectionInput>(
      nh, pnh.param<std::string>("recalibration/reference_topic", "reference_sun_vector"), max_stamp_difference_s,
      "reference");
  geometry_pub_ = nh.advertise<digital_sun_sensor::UnitGeometry>("unit_geometry", 1, true);
  save_service_ = pnh.advertiseService("save_unit_model", &InFlightRecalibration::onSave, this);
}

void InFlightRecalibration::offer(const std::vector<cv::Mat>& images, const std::vector<std_msgs::Header>& headers,
                                  const std::vector<SunEstimate>& estimates) {
  std::vector<cv::Mat> paired;
  std::vector<std::array<double, 2>> references;
  std::vector<const SunEstimate*> estimated;
  for (std::size_t i = 0; i < images.size(); ++i) {
    // Estimates the unit's drift makes inconsistent still pair: that is what
    // the refit is for.
    const SunEstimate& e = estimates[i];
    if (!e.valid && status::statusCode(e.status) != status::kModelMismatch) continue;
    const std::optional<std::array<double, 2>> angles = references_->forImage(headers[i]);
    if (!angles) continue;
    paired.push_back(images[i]);
    references.push_back(*angles);
    estimated.push_back(&e);
  }
  if (paired.empty()) return;
  // Every pair counts for consistency, also those the refit refuses as too
  // far off: a drifted unit's are what it must see.
  for (std::size_t k = 0; k < estimated.size(); ++k) consistency_.add(*estimated[k], references[k]);
  judged_ = consistency_;
  const std::vector<UnitImage> reads = estimator_.readUnit(paired, references);
  std::string summary;
  // Due is judged pair by pair (every refit_every pairs, whatever the batches).
  for (std::size_t k = 0; k < reads.size() && k < estimated.size(); ++k) {
    recalibrator_.add(reads[k], estimated[k]->alpha_rad, estimated[k]->beta_rad);
    if (!recalibrator_.due()) continue;
    try {
      const UnitCalibrationReport r = estimator_.recalibrate(recalibrator_);
      consistency_.reset();  // the earlier residuals were the old geometry's
      auto msg = boost::make_shared<digital_sun_sensor::UnitGeometry>();
      msg->header.stamp = headers.back().stamp;
      msg->header.frame_id = headers.back().frame_id;
      msg->height_um = r.after.height_um;
      msg->offset_x_um = r.after.offset_x_um;
      msg->offset_y_um = r.after.offset_y_um;
      msg->rotation_rad = r.after.rotation_rad;
      msg->tilt_x_rad = r.after.tilt_x_rad;
      msg->tilt_y_rad = r.after.tilt_y_rad;
      for (std::size_t k = 0; k < 6; ++k) msg->standard_errors[k] = r.standard_errors[k];
      msg->pairs = static_cast<std::uint32_t>(recalibrator_.pairs());
      msg->spots = static_cast<std::uint32_t>(r.spots);
      msg->spread_deg = recalibrator_.spreadDeg();
      msg->spot_rms_um_before = r.spot_rms_um_before;
      msg->spot_rms_um_after = r.spot_rms_um_after;
      geometry_pub_.publish(msg);
      std::ostringstream s;
      s << r.spots << " spots of " << recalibrator_.pairs() << " pairs, spot RMS " << r.spot_rms_um_before << " -> "
        << r.spot_rms_um_after << " um, height " << r.after.height_um - r.before.height_um << " um";
      summary = s.str();
      ROS_INFO_THROTTLE(10.0, "calibration_node: unit geometry refitted: %s", summary.c_str());
    } catch (const std::invalid_argument& e) {
      ROS_WARN_THROTTLE(10.0, "calibration_node: unit geometry not refitted: %s", e.what());
      std::lock_guard<std::mutex> lock(stats_mutex_);
      ++refit_failures_;
    }
  }
  std::lock_guard<std::mutex> lock(stats_mutex_);
  pairs_ = recalibrator_.pairs();
  refused_ = recalibrator_.refused();
  refits_ = recalibrator_.refits();
  spread_deg_ = recalibrator_.spreadDeg();
  if (!summary.empty()) last_refit_ = summary;
  consistency_pairs_ = judged_.pairs();
  consistency_normalized_ = judged_.normalizedRms();
  widened_by_deg_ = {radToDeg(judged_.extraSigmaRad()[0]), radToDeg(judged_.extraSigmaRad()[1])};
}

bool InFlightRecalibration::onSave(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& response) {
  if (output_path_.empty()) {
    response.success = false;
    response.message = "~recalibration/output is not set: no file to write";
    return true;
  }
  std::lock_guard<std::mutex> lock(estimator_mutex_);
  if (recalibrator_.refits() == 0) {
    response.success = false;
    response.message = "no refit yet (" + std::to_string(recalibrator_.pairs()) + " pairs, spread " +
                       std::to_string(recalibrator_.spreadDeg()) + " deg): nothing new to save";
    return true;
  }
  try {
    YAML::Node record = YAML::Load(recalibrator_.last()->toYaml());
    record["data"] = "in flight: " + std::to_string(recalibrator_.pairs()) + " reference pairs, " +
                     std::to_string(recalibrator_.refits()) + " refits, from " + model_path_;
    estimator_.saveModel(output_path_, YAML::Dump(record));
    response.success = true;
    response.message = "wrote " + output_path_;
  } catch (const std::exception& e) {
    response.success = false;
    response.message = std::string("could not write ") + output_path_ + ": " + e.what();
  }
  return true;
}

void InFlightRecalibration::diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat) {
  const SunDirectionInput::Counts counts = references_->counts();
  std::lock_guard<std::mutex> lock(stats_mutex_);
  stat.add("recalibration references received", counts.received);
  stat.add("recalibration pairs in window", pairs_);
  stat.add("recalibration references refused", refused_);
  stat.add("recalibration images without reference", counts.unpaired_images);
  stat.add("recalibration references in unresolved frames", counts.unresolved_frames);
  stat.add("recalibration spread [deg]", spread_deg_);
  stat.add("recalibration refits", refits_);
  stat.add("recalibration failed refits", refit_failures_);
  stat.add("recalibration last refit", last_refit_.empty() ? "none" : last_refit_);
  stat.add("reference consistency pairs", consistency_pairs_);
  stat.addf("reference residual / sigma (robust RMS)", "%.2f / %.2f", consistency_normalized_[0],
            consistency_normalized_[1]);
  stat.addf("sigma widened by [deg]", "%.6f / %.6f", widened_by_deg_[0], widened_by_deg_[1]);
  if (widened_by_deg_[0] > 0.0 || widened_by_deg_[1] > 0.0)
    stat.mergeSummaryf(diagnostic_msgs::DiagnosticStatus::WARN,
                       "estimates disagree with the reference (%.1f / %.1f sigma): sigma widened by %.4f / %.4f deg "
                       "until the unit's geometry is refitted",
                       consistency_normalized_[0], consistency_normalized_[1], widened_by_deg_[0], widened_by_deg_[1]);
}

}  // namespace dss
