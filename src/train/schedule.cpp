// The schedule: batch size, steps per epoch, warm-up + cosine learning rate,
// the seeded data order of each epoch.
#include <algorithm>
#include <cmath>
#include <numeric>

#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/common/units.h"
#include "trainer_impl.h"

namespace dss {

std::int64_t Trainer::Impl::imagesPerStep() const {
  return std::min<std::int64_t>(options.batch_size, static_cast<std::int64_t>(train.size()));
}

std::int64_t Trainer::Impl::stepsPerEpoch() const {
  return std::max<std::int64_t>(1, static_cast<std::int64_t>(train.size()) / options.batch_size);
}

double Trainer::Impl::learningRate(std::int64_t global_step) const {
  const double total = static_cast<double>(stepsPerEpoch()) * options.epochs;
  const double warmup = std::max(1.0, options.warmup_fraction * total);
  const double s = static_cast<double>(global_step);
  if (s < warmup) return options.learning_rate * (s + 1) / warmup;
  const double t = std::min(1.0, (s - warmup) / std::max(1.0, total - warmup));
  const double floor = options.final_lr_fraction;
  return options.learning_rate * (floor + (1 - floor) * 0.5 * (1 + std::cos(kPi * t)));
}

// The epoch's data order: a seeded permutation, so a resumed run sees the same.
std::vector<std::size_t> Trainer::Impl::epochOrder(int e) const {
  std::vector<std::size_t> order(train.size());
  std::iota(order.begin(), order.end(), 0);
  Rng rng(deriveSeed(options.seed, 0xE90C0000ULL + static_cast<std::uint64_t>(e)));
  for (std::size_t i = order.size(); i > 1; --i) std::swap(order[i - 1], order[rng.below(i)]);
  return order;
}

}  // namespace dss
