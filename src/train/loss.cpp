#include "digital_sun_sensor/train/loss.h"

#include <torch/nn/functional/loss.h>

namespace dss {

torch::Tensor trainingLoss(const SscnnOutput& out, const torch::Tensor& target, const torch::Tensor& classes,
                           double residual_scale, double class_weight) {
  // A full Gaussian NLL on the angles lets the network buy a small loss on
  // hard images (spots cut by the edge) with a large variance, and the worst
  // errors grow; the variance learns from the detached error instead, so it
  // is honest without steering the angles (README "Training").
  const auto error = out.angles - target;
  const auto mse = error.pow(2).mean() / (residual_scale * residual_scale);
  const auto nll = (0.5 * error.detach().pow(2) * torch::exp(-out.log_variance) + 0.5 * out.log_variance).mean();
  auto loss = mse + nll;
  if (class_weight > 0) loss = loss + class_weight * torch::cross_entropy_loss(out.class_logits, classes);
  return loss;
}

}  // namespace dss
