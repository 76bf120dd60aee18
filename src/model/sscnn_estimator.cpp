#include "digital_sun_sensor/model/sscnn_estimator.h"

#include <yaml-cpp/yaml.h>

#include <iomanip>
#include <sstream>
#include <stdexcept>

#include "digital_sun_sensor/common/estimate_status.h"
#include "digital_sun_sensor/model/input_envelope.h"
#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/model/symmetry.h"

namespace dss {

struct SscnnEstimator::Impl {
  Model model;
  SensorConfig sensor;
  InputEnvelope envelope;
};

SscnnEstimator::SscnnEstimator(const std::string& model_path, const SensorConfig* expected, bool mirror_average)
    : impl_(std::make_unique<Impl>()) {
  impl_->model = loadModel(model_path, expected);
  if (!mirror_average) impl_->model.meta.inference_symmetry = InferenceSymmetry::kNone;
  impl_->sensor = parseSensorConfig(impl_->model.meta.sensor_yaml, model_path + " (sensor)");
  impl_->envelope = inputEnvelopeOf(impl_->model.meta);
}

SscnnEstimator::~SscnnEstimator() = default;

void SscnnEstimator::warmUp(int threads) const { impl_->model.net->warmUp(threads); }

const SensorConfig& SscnnEstimator::sensor() const { return impl_->sensor; }

std::string SscnnEstimator::inferenceSymmetry() const {
  return inferenceSymmetryName(impl_->model.meta.inference_symmetry);
}

bool SscnnEstimator::hasGeometry() const { return impl_->model.meta.arch.geometric_head; }

std::vector<UnitImage> SscnnEstimator::readUnit(const std::vector<cv::Mat>& images,
                                                const std::vector<std::array<double, 2>>& reference_rad) const {
  return readUnitImages(impl_->model, images, reference_rad);
}

UnitCalibrationReport SscnnEstimator::recalibrate(UnitRecalibrator& recalibrator) {
  return recalibrator.refit(impl_->model);
}

MaskGeometry SscnnEstimator::geometry() const {
  if (!hasGeometry()) throw std::invalid_argument("the model has no geometric head");
  return impl_->model.net->geometry()->maskGeometry();
}

void SscnnEstimator::saveModel(const std::string& path, const std::string& record) const {
  Model copy = impl_->model;  // the record goes to the file only
  copy.meta.unit_yaml = record;
  dss::saveModel(copy, path);
}

double SscnnEstimator::mismatchThreshold() const { return impl_->model.meta.mismatch_threshold; }

std::string SscnnEstimator::unitCalibration() const {
  if (impl_->model.meta.unit_yaml == "{}") return "";
  try {
    const YAML::Node unit = YAML::Load(impl_->model.meta.unit_yaml);
    return unit["data"] ? unit["data"].as<std::string>() : "calibrated";
  } catch (const YAML::Exception&) {
    return "calibrated";
  }
}

std::vector<SunEstimate> SscnnEstimator::estimate(const std::vector<cv::Mat>& images) {
  return estimateWith(images, nullptr);
}

std::vector<SunEstimate> SscnnEstimator::estimateWithCoarseDirections(const std::vector<cv::Mat>& images,
                                                                      const CoarseDirections& coarse) {
  if (coarse.size() != images.size())
    throw std::invalid_argument(std::to_string(coarse.size()) + " coarse directions for " +
                                std::to_string(images.size()) + " images");
  // A pattern head reads the image alone (no mirror images averaged).
  const bool takes_coarse =
      impl_->model.meta.arch.pattern_head && symmetryTransforms(impl_->model.meta.inference_symmetry).size() == 1;
  return estimateWith(images, takes_coarse ? &coarse : nullptr);
}

std::vector<SunEstimate> SscnnEstimator::estimateWith(const std::vector<cv::Mat>& images,
                                                      const CoarseDirections* coarse) {
  std::vector<SunEstimate> out(images.size());
  // Unusable images are answered individually; the rest run as one batch.
  std::vector<cv::Mat> usable;
  std::vector<std::size_t> where;
  CoarseDirections usable_coarse;
  for (std::size_t i = 0; i < images.size(); ++i) {
    try {
      impl_->model.meta.input.checkImage(images[i]);
      usable.push_back(images[i]);
      where.push_back(i);
      if (coarse) usable_coarse.push_back((*coarse)[i]);
    } catch (const std::invalid_argument& e) {
      out[i].status = status::withDetail(status::kBadImage, e.what());
    }
  }
  if (usable.empty()) return out;
  const std::vector<Prediction> predictions = impl_->model.predict(usable, coarse ? &usable_coarse : nullptr);
  for (std::size_t k = 0; k < predictions.size(); ++k) {
    const Prediction& p = predictions[k];
    SunEstimate& e = out[where[k]];
    e.alpha_rad = p.alpha_rad;
    e.beta_rad = p.beta_rad;
    e.covariance = {p.alpha_variance_rad2, 0.0, 0.0, p.beta_variance_rad2};
    e.subfov_class = p.subfov_class;
    e.spot_mismatch = p.spot_mismatch;
    e.model_sigma_rad = impl_->model.meta.geometry_sigma_rad;
    e.valid = p.active_sites > 0;
    if (!e.valid) {
      e.status = status::kNoSun;
    } else if (!impl_->envelope.contains(p.active_sites)) {
      e.valid = false;
      e.status = status::withDetail(status::kOutOfDistribution,
                                    std::to_string(p.active_sites) +
                                        " lit pixels (training: " + std::to_string(impl_->envelope.min_sites) + ".." +
                                        std::to_string(impl_->envelope.max_sites) + ")");
    } else if (!p.declined.empty()) {
      e.valid = false;
      e.status = p.declined;
    } else if (p.code_margin < kMinApertureCodeMargin) {
      e.valid = false;
      std::ostringstream detail;
      detail << status::kAmbiguousAperture << ": the runner-up lattice placement fits the spot sizes only "
             << std::setprecision(3) << p.code_margin << " times worse (needs " << kMinApertureCodeMargin << ")";
      e.status = detail.str();
    } else if (p.lone_spot_ambiguous) {
      e.valid = false;
      e.status = status::withDetail(status::kAmbiguousAperture,
                                    "one spot lit, and another aperture (of another size) could have made it");
    } else if (impl_->model.meta.mismatch_threshold > 0.0 && p.spot_mismatch > impl_->model.meta.mismatch_threshold) {
      // The estimate is kept (angles, sigma) but not trusted: the geometry
      // it was solved through is not the unit's.
      e.valid = false;
      std::ostringstream detail;
      detail << status::kModelMismatch << ": the spots lie " << std::setprecision(3) << p.spot_mismatch
             << " times their calibrated residual from the model's geometry (threshold "
             << impl_->model.meta.mismatch_threshold << "); calibrate the unit (dss calibrate-unit)";
      e.status = detail.str();
    }
  }
  return out;
}

}  // namespace dss
