#include "digital_sun_sensor/train/loss.h"

#include <torch/nn/functional/loss.h>

namespace dss {

torch::Tensor trainingLoss(const SscnnOutput& out, const torch::Tensor& target, const torch::Tensor& classes,
                           double residual_scale, double class_weight) {
  // A full Gaussian NLL on the angles lets the network buy a small loss on
  // hard images (spots cut by the edge) with a large variance, and the worst
  // errors grow; the variance learns from the detached error instead, so it
  // is honest without steering the angles (docs/training.md).
  const auto error = out.angles - target;
  // An image whose lattice was resolved to another aperture than the true
  // one (stray light swelling the spots unevenly misleads the aperture code)
  // is whole pitches off, tens of degrees. No gradient mends a discrete
  // choice, and such an error would swamp its batch and, for about a thousand
  // steps, AdamW's second moments: it is left out of the angle terms.
  auto keep = torch::ones({error.size(0), 1}, error.options());
  if (out.resolved_class.defined() && !out.coarse_angles.defined())  // lattice heads
    keep = (out.resolved_class.to(torch::kLong) == classes.to(torch::kLong)).to(error.scalar_type()).unsqueeze(1);
  const auto kept_terms = (2.0 * keep.sum()).clamp_min(1.0);
  const auto mse = (error.pow(2) * keep).sum() / kept_terms / (residual_scale * residual_scale);
  const auto nll =
      ((0.5 * error.detach().pow(2) * torch::exp(-out.log_variance) + 0.5 * out.log_variance) * keep).sum() /
      kept_terms;
  auto loss = mse + nll;
  // The geometric head's coarse angles only associate the sites with the
  // apertures, but must be right to half the spots' spacing for that: their
  // own squared error, on the scale of the angles'.
  if (out.coarse_angles.defined())
    loss = loss + (out.coarse_angles - target).pow(2).mean() / (residual_scale * residual_scale);
  if (class_weight > 0) loss = loss + class_weight * torch::cross_entropy_loss(out.class_logits, classes);
  return loss;
}

}  // namespace dss
