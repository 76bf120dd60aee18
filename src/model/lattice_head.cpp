// The lattice head: the whole pitches added to the phase (aperture code,
// known or predicted classes, or the coarse centroid).
#include <torch/nn/functional/activation.h>
#include <torch/nn/functional/conv.h>
#include <torch/nn/functional/pooling.h>

#include <algorithm>
#include <cmath>

#include "digital_sun_sensor/model/sscnn.h"
#include "digital_sun_sensor/sparse/ops.h"

namespace dss {

using sparse::RulebookCache;
using sparse::SparseTensor;
namespace F = torch::nn::functional;

torch::Tensor SscnnNetImpl::latticeSteps(int axis, const torch::TensorOptions& options) const {
  const double pitch = arch_.latticePitch(axis);
  const int count = arch_.latticeCount(axis);
  // With an even count the spots sit half a pitch off the lattice centre.
  const double half_pitch = count % 2 == 0 ? 0.5 : 0.0;
  const int reach = static_cast<int>(std::ceil(std::max(1.5, 0.5 * count * pitch) / pitch)) + 1;
  return (torch::arange(-reach, reach + 1, options) + half_pitch) * pitch;
}

torch::Tensor SscnnNetImpl::resolveLattice(const SpotReading& spots, const torch::Tensor& class_logits,
                                           const torch::Tensor& known_classes) const {
  // The aperture code, in training too: the true class (the aperture whose
  // spot is nearest the detector centre) implies the shift only to within
  // half a pitch, which near the edge of the field, where the nearest spot
  // may lie further out, picks the wrong pitch.
  if (spots.code_steps.defined()) return spots.phase + spots.code_steps;
  torch::Tensor class_estimate;  // lattice shift the classes imply, [B, 2]
  if (known_classes.defined() && class_logits.defined()) {
    class_estimate = -lattice_class_offsets_.index_select(0, known_classes.to(torch::kLong));
  } else if (class_logits.defined()) {
    torch::NoGradGuard no_grad;
    // Expected over the class probabilities: between two neighbouring classes
    // the estimate stays within half a pitch of the truth.
    class_estimate = -torch::softmax(class_logits.detach(), 1).matmul(lattice_class_offsets_);
  }
  std::vector<torch::Tensor> shift(2);
  for (int axis = 0; axis < 2; ++axis) {
    const double pitch = arch_.latticePitch(axis);
    const int count = arch_.latticeCount(axis);
    const torch::Tensor phase = spots.phase.slice(1, axis, axis + 1);
    const torch::Tensor steps = latticeSteps(axis, phase.options());  // [K]
    torch::Tensor chosen_step;
    {
      torch::NoGradGuard no_grad;  // a discrete choice: gradients flow through the phase only
      const torch::Tensor candidates = phase.detach() + steps.unsqueeze(0);  // [B, K]
      torch::Tensor mismatch;
      if (class_estimate.defined()) {
        mismatch = (candidates - class_estimate.slice(1, axis, axis + 1)).abs();
      } else {
        // Each candidate predicts the centroid of the spots it leaves on the
        // detector (fading out over a spot radius at the edge); among those
        // the spots' presence does not contradict, the one nearest the
        // measured centroid wins. (The centroid alone, weighted by brightness,
        // goes wrong where a ghost brightens some spots and, through the
        // exposure, dims the others.)
        const torch::Tensor offsets = (torch::arange(count, phase.options()) - 0.5 * (count - 1)) * pitch;  // [n]
        const torch::Tensor lattice = candidates.unsqueeze(2) + offsets.view({1, 1, -1});                   // [B, K, n]
        const torch::Tensor visible = ((1.0 - lattice.abs()) / arch_.lattice_spot_radius + 0.5).clamp(0.0, 1.0);
        const torch::Tensor visible_total = visible.sum(2);
        const torch::Tensor predicted = (visible * lattice).sum(2) / visible_total.clamp_min(1e-6);
        mismatch = (predicted - spots.centroid.slice(1, axis, axis + 1).detach()).abs() +
                   (visible_total < 1e-3).to(predicted.scalar_type()) * 1e6;
        if (spots.contradictions[axis].defined()) mismatch = mismatch + spots.contradictions[axis] * 1e3;
      }
      chosen_step = steps.index_select(0, mismatch.argmin(1)).unsqueeze(1);
    }
    shift[axis] = phase + chosen_step;
  }
  return torch::cat(shift, 1);
}

}  // namespace dss
