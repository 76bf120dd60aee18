#include "digital_sun_sensor/train/training_set.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <stdexcept>

#include "digital_sun_sensor/common/limits.h"
#include "digital_sun_sensor/common/random.h"

namespace dss {

void TrainingSet::add(const cv::Mat& image, double alpha_rad, double beta_rad, int subfov_class) {
  spec_.checkImage(image);
  SparseSample s;
  s.alpha_rad = alpha_rad;
  s.beta_rad = beta_rad;
  s.subfov_class = subfov_class;
  for (const ActivePixel& p : pixelsAboveThreshold(image, spec_)) {
    s.pixels.push_back((static_cast<std::uint32_t>(p.y) << 16) | static_cast<std::uint32_t>(p.x));
    s.dn.push_back(static_cast<std::uint16_t>(p.dn));
  }
  add(std::move(s));
}

void TrainingSet::add(SparseSample sample) {
  const std::uint64_t bytes = sizeof(SparseSample) + sample.pixels.size() * 4 + sample.dn.size() * 2;
  if (pixel_bytes_ + bytes > limits::kMaxTrainingSetBytes)
    throw limits::LimitExceeded("training images in memory: " + std::to_string(samples_.size()) +
                                " images fill the limit of " + limits::describeBytes(limits::kMaxTrainingSetBytes) +
                                " (use fewer or smaller bags, or a higher input threshold)");
  pixel_bytes_ += bytes;
  samples_.push_back(std::move(sample));
}

int TrainingSet::siteCount(const SparseSample& sample, int max_sites) const {
  return static_cast<int>(std::min<std::size_t>(sample.pixels.size(), static_cast<std::size_t>(max_sites)));
}

std::vector<int> TrainingSet::siteCounts(int max_sites) const {
  std::vector<int> counts;
  counts.reserve(samples_.size());
  for (const auto& s : samples_) counts.push_back(siteCount(s, max_sites));
  return counts;
}

std::size_t TrainingSet::memoryBytes() const {
  std::size_t bytes = samples_.capacity() * sizeof(SparseSample);
  for (const auto& s : samples_) bytes += s.pixels.capacity() * 4 + s.dn.capacity() * 2;
  return bytes;
}

void TrainingSet::split(double validation_fraction, std::uint64_t seed, TrainingSet& train,
                        TrainingSet& validation) const {
  std::vector<std::size_t> order(samples_.size());
  std::iota(order.begin(), order.end(), 0);
  Rng rng(deriveSeed(seed, 0x5B117));
  for (std::size_t i = order.size(); i > 1; --i) std::swap(order[i - 1], order[rng.below(i)]);
  std::size_t n_val = static_cast<std::size_t>(std::llround(validation_fraction * static_cast<double>(order.size())));
  if (validation_fraction > 0 && n_val == 0 && order.size() >= 2) n_val = 1;
  n_val = std::min(n_val, order.size());
  train = TrainingSet(spec_);
  validation = TrainingSet(spec_);
  // Validation keeps dataset order so that its report reads like the bag.
  std::vector<std::size_t> val_idx(order.begin(), order.begin() + static_cast<std::ptrdiff_t>(n_val));
  std::sort(val_idx.begin(), val_idx.end());
  for (std::size_t i : val_idx) validation.add(samples_[i]);
  std::vector<std::size_t> train_idx(order.begin() + static_cast<std::ptrdiff_t>(n_val), order.end());
  std::sort(train_idx.begin(), train_idx.end());
  for (std::size_t i : train_idx) train.add(samples_[i]);
}

void setAugmentation(AugmentationConfig& config, const std::string& key, double value) {
  const std::pair<const char*, double*> fields[] = {
      {"gain_probability", &config.gain_probability},
      {"gain_sigma", &config.gain_sigma},
      {"noise_probability", &config.noise_probability},
      {"noise_sigma_dn", &config.noise_sigma_dn},
      {"threshold_probability", &config.threshold_probability},
      {"threshold_max_fraction", &config.threshold_max_fraction},
      {"dropout_probability", &config.dropout_probability},
      {"dropout_max_radius_px", &config.dropout_max_radius_px},
  };
  std::string known;
  for (const auto& [name, field] : fields) {
    if (key == name) {
      if (!std::isfinite(value) || value < 0)
        throw std::invalid_argument("augmentation '" + key + "' must be a finite value >= 0");
      *field = value;
      return;
    }
    known += (known.empty() ? "" : ", ") + std::string(name);
  }
  throw std::invalid_argument("unknown augmentation '" + key + "' (known: " + known + ")");
}

void setAugmentation(AugmentationConfig& config, const std::string& assignment) {
  const auto eq = assignment.find('=');
  if (eq == std::string::npos) throw std::invalid_argument("augmentation '" + assignment + "' is not key=value");
  const std::string value = assignment.substr(eq + 1);
  std::size_t used = 0;
  double v = 0;
  try {
    v = std::stod(value, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used == 0 || used != value.size())
    throw std::invalid_argument("augmentation '" + assignment + "': '" + value + "' is not a number");
  setAugmentation(config, assignment.substr(0, eq), v);
}

SparseSample augment(const SparseSample& sample, const InputSpec& spec, const AugmentationConfig& config,
                     std::uint64_t seed) {
  if (!config.enabled() || sample.dn.empty()) return sample;
  Rng rng(seed);
  const bool gain = rng.uniform() < config.gain_probability;
  const bool noise = rng.uniform() < config.noise_probability;
  const bool threshold = rng.uniform() < config.threshold_probability;
  const bool dropout = rng.uniform() < config.dropout_probability;
  if (!gain && !noise && !threshold && !dropout) return sample;

  const double gain_factor = gain ? std::exp(config.gain_sigma * rng.normal()) : 1.0;
  const double noise_sigma = noise ? rng.uniform(0.0, config.noise_sigma_dn) : 0.0;
  const int peak = *std::max_element(sample.dn.begin(), sample.dn.end());
  const double extra_threshold =
      threshold ? rng.uniform(0.0, config.threshold_max_fraction) * (peak - spec.black_level_dn) : 0.0;
  double drop_x = 0, drop_y = 0, drop_r2 = -1;
  if (dropout) {
    const std::uint32_t p = sample.pixels[rng.below(sample.pixels.size())];
    drop_x = p & 0xFFFF;
    drop_y = p >> 16;
    const double r = rng.uniform(0.0, config.dropout_max_radius_px);
    drop_r2 = r * r;
  }
  SparseSample out;
  out.alpha_rad = sample.alpha_rad;
  out.beta_rad = sample.beta_rad;
  out.subfov_class = sample.subfov_class;
  for (std::size_t i = 0; i < sample.dn.size(); ++i) {
    const double x = sample.pixels[i] & 0xFFFF, y = sample.pixels[i] >> 16;
    if (drop_r2 >= 0 && (x - drop_x) * (x - drop_x) + (y - drop_y) * (y - drop_y) <= drop_r2) continue;
    double v = spec.black_level_dn + (sample.dn[i] - spec.black_level_dn) * gain_factor;
    if (noise_sigma > 0) v += noise_sigma * rng.normal();
    v = std::min<double>(std::round(v), spec.max_code);
    if (v <= spec.threshold_dn || v - spec.black_level_dn <= extra_threshold) continue;
    out.pixels.push_back(sample.pixels[i]);
    out.dn.push_back(static_cast<std::uint16_t>(v));
  }
  return out.dn.empty() ? sample : out;
}

}  // namespace dss
