// One optimizer step: augmented batch, forward, loss, backward, AdamW.
#include <algorithm>

#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/model/sparse_input.h"
#include "digital_sun_sensor/train/loss.h"
#include "trainer_impl.h"

namespace dss {

// One optimizer step on the batch at (epoch, step); returns the loss.
double Trainer::Impl::step(const std::vector<std::size_t>& order) {
  const auto b0 = static_cast<std::size_t>(step_in_epoch * options.batch_size);
  std::vector<SparseSample> augmented;
  augmented.reserve(static_cast<std::size_t>(options.batch_size));
  std::vector<float> targets;
  std::vector<std::int64_t> classes;
  // A training set smaller than a batch makes one short batch per epoch.
  const std::size_t b1 = std::min(order.size(), b0 + static_cast<std::size_t>(options.batch_size));
  for (std::size_t k = b0; k < b1; ++k) {
    const SparseSample& s = train.samples()[order[k]];
    augmented.push_back(augment(s, train.spec(), options.augmentation,
                                deriveSeed(options.seed, (static_cast<std::uint64_t>(epoch) << 32) + k)));
    targets.push_back(static_cast<float>(s.alpha_rad / model.meta.angle_scale_rad));
    targets.push_back(static_cast<float>(s.beta_rad / model.meta.angle_scale_rad));
    classes.push_back(std::max(0, s.subfov_class));
  }
  std::vector<const SparseSample*> batch;
  for (const auto& s : augmented) batch.push_back(&s);
  const auto input = encodeSamples(batch, train.spec());
  const auto target = torch::tensor(targets).view({-1, 2});

  const double lr = learningRate(epoch * stepsPerEpoch() + step_in_epoch);
  for (auto& group : optimizer->param_groups()) static_cast<torch::optim::AdamWOptions&>(group.options()).lr(lr);
  last.learning_rate = lr;
  optimizer->zero_grad();
  // The true classes resolve a class-resolved lattice while training, so the
  // angles learn from the right pitch before the classifier has learned; the
  // true angles associate the geometric head's sites, so the angles learn
  // from the right apertures before the coarse estimate has learned.
  const auto class_tensor = torch::tensor(classes);
  const auto out = model.net->forward(input, class_tensor, target);
  const double class_weight = sensor.numSubFovClasses() > 1 ? options.class_loss_weight : 0.0;
  const auto loss = trainingLoss(out, target, class_tensor, model.meta.arch.residual_scale, class_weight);
  loss.backward();
  optimizer->step();
  return loss.item<double>();
}

}  // namespace dss
