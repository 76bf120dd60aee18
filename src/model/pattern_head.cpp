// The pattern head: a mask whose spots merge (thesis_ca) solved whole by
// the sensor design's pattern estimator, on the image its sites make.
#include <cmath>
#include <opencv2/core.hpp>
#include <optional>
#include <stdexcept>

#include "digital_sun_sensor/baseline/pattern_estimator.h"
#include "digital_sun_sensor/model/sscnn.h"

namespace dss {

void SscnnNetImpl::initPattern(const SensorConfig& config, const InputSpec& input) {
  if (!arch_.pattern_head) return;
  PatternEstimatorOptions options;
  options.sigma_images = 0;  // the model's sigma level is fitted on held-out images (calibrate-sigma)
  pattern_ = std::make_shared<const PatternEstimator>(config, options);
  pattern_input_ = input;
}

void SscnnNetImpl::warmUp(int threads) const {
  if (pattern_) pattern_->warmUp(threads);
}

SscnnOutput SscnnNetImpl::patternForward(const sparse::SparseTensor& input, const torch::Tensor& coarse) {
  if (!pattern_) throw std::logic_error("pattern head: the sensor's pattern estimator was not made (initPattern)");
  const std::int64_t batch = input.sites->batchSize();
  const InputSpec& spec = pattern_input_;
  // The sites' values back to digital numbers (BatchEncoder's scaling),
  // every other pixel dark.
  const int type = spec.max_code > 255 ? CV_16U : CV_8U;
  std::vector<cv::Mat> images;
  for (std::int64_t b = 0; b < batch; ++b) images.push_back(cv::Mat::zeros(spec.height_px, spec.width_px, type));
  const double dn_per_value = std::max(1.0, spec.max_code - spec.black_level_dn);
  const torch::Tensor values = input.features.select(1, 0).to(torch::kDouble).contiguous();
  const auto value = values.accessor<double, 1>();
  const auto& sites = input.sites->sites();
  for (std::size_t k = 0; k < sites.size(); ++k) {
    const int dn =
        static_cast<int>(std::lround(value[static_cast<std::int64_t>(k)] * dn_per_value + spec.black_level_dn));
    cv::Mat& image = images[static_cast<std::size_t>(sites[k].batch)];
    if (type == CV_16U)
      image.at<std::uint16_t>(sites[k].y, sites[k].x) = static_cast<std::uint16_t>(dn);
    else
      image.at<std::uint8_t>(sites[k].y, sites[k].x) = static_cast<std::uint8_t>(dn);
  }
  return patternForward(images, coarse, input.features.scalar_type());
}

SscnnOutput SscnnNetImpl::patternForward(const std::vector<cv::Mat>& images, const torch::Tensor& coarse,
                                         torch::Dtype dtype) {
  if (!pattern_) throw std::logic_error("pattern head: the sensor's pattern estimator was not made (initPattern)");
  const auto batch = static_cast<std::int64_t>(images.size());
  const double scale = arch_.angle_scale_rad;
  torch::Tensor angles = torch::zeros({batch, 2}, torch::kDouble);
  torch::Tensor solve_log_variance = torch::zeros({batch, 2}, torch::kDouble);
  torch::Tensor log_inflation = torch::zeros({batch, 1}, torch::kDouble);
  torch::Tensor classes = torch::zeros({batch}, torch::kLong);
  auto a = angles.accessor<double, 2>(), v = solve_log_variance.accessor<double, 2>();
  auto inflate = log_inflation.accessor<double, 2>();
  auto c = classes.accessor<std::int64_t, 1>();
  SscnnOutput out;
  out.declined.resize(static_cast<std::size_t>(batch));
  for (std::int64_t b = 0; b < batch; ++b) {
    std::optional<CoarseDirection> direction;
    if (coarse.defined()) {
      const auto row = coarse[b].to(torch::kDouble);
      if (std::isfinite(row[2].item<double>()))
        direction = CoarseDirection{row[0].item<double>() * scale, row[1].item<double>() * scale,
                                    row[2].item<double>() * scale};
    }
    const SunEstimate e = pattern_->estimateOne(images[static_cast<std::size_t>(b)], {}, direction);
    c[b] = std::max(e.subfov_class, 0);
    if (!e.valid) {
      out.declined[static_cast<std::size_t>(b)] = e.status;
      continue;
    }
    a[b][0] = e.alpha_rad / scale;
    a[b][1] = e.beta_rad / scale;
    // The solve's own variance to the variance head; its inflation for
    // light the design does not hold apart, added after it.
    inflate[b][0] = std::log(PatternEstimator::varianceInflation(e.unexplained_light_z));
    v[b][0] = std::log(e.covariance[0] / (scale * scale)) - inflate[b][0];
    v[b][1] = std::log(e.covariance[3] / (scale * scale)) - inflate[b][0];
  }
  out.angles = angles.to(dtype);
  out.class_logits = torch::zeros({batch, arch_.num_classes}, torch::TensorOptions().dtype(dtype));
  out.resolved_class = classes;
  // The variance head as for the geometric head: its weights on the
  // solve's log variance (identity as created), none on features here.
  // Then the inflation for light the design does not hold, whatever the
  // head's calibration (a constant sigma zeroes its weights).
  const std::int64_t features = variance_->weight.size(1) - 2;
  out.log_variance =
      variance_->forward(torch::cat(
          {torch::zeros({batch, features}, torch::TensorOptions().dtype(dtype)), solve_log_variance.to(dtype)}, 1)) +
      log_inflation.to(dtype);
  return out;
}

}  // namespace dss
