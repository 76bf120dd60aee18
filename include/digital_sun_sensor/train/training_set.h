// Labelled images held compactly for training: only the pixels that can be
// active sites (above the input threshold) are kept, so tens of thousands of
// 512 x 512 images fit in memory. Torch-free.
#pragma once

#include <cstdint>
#include <functional>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "digital_sun_sensor/model/input_spec.h"

namespace dss {

// (done, total) samples of a long pass over a training set, for a progress line.
using SampleProgress = std::function<void(std::size_t, std::size_t)>;

struct SparseSample {
  std::vector<std::uint32_t> pixels;  // (y << 16) | x, row-major order
  std::vector<std::uint16_t> dn;      // digital number of each pixel
  double alpha_rad = 0.0;
  double beta_rad = 0.0;
  int subfov_class = -1;
};

class TrainingSet {
 public:
  explicit TrainingSet(InputSpec spec) : spec_(spec) {}

  // Keeps the pixels above spec.threshold_dn. Throws std::invalid_argument
  // when the image disagrees with the spec, limits::LimitExceeded when the
  // set would outgrow limits::kMaxTrainingSetBytes.
  void add(const cv::Mat& image, double alpha_rad, double beta_rad, int subfov_class);
  void add(SparseSample sample);

  const InputSpec& spec() const { return spec_; }
  const std::vector<SparseSample>& samples() const { return samples_; }
  std::size_t size() const { return samples_.size(); }
  std::size_t memoryBytes() const;
  // Active sites a sample gives a model whose input keeps at most
  // `max_sites` per image (its InputSpec's: the pattern head keeps every lit
  // pixel, more than the data's own spec).
  int siteCount(const SparseSample& sample, int max_sites) const;
  // The same for each sample.
  std::vector<int> siteCounts(int max_sites) const;

  // Deterministic split: a seeded shuffle, the first `validation_fraction`
  // (at least one sample when there are two or more) goes to validation.
  void split(double validation_fraction, std::uint64_t seed, TrainingSet& train, TrainingSet& validation) const;

 private:
  InputSpec spec_;
  std::vector<SparseSample> samples_;
  std::uint64_t pixel_bytes_ = 0;  // of every sample's pixels and values
};

// Rates of the augmentation applied to training samples (each independently
// per sample), so that one model tolerates a range of sensor conditions.
struct AugmentationConfig {
  double gain_probability = 0.0;        // scale every DN by a random gain...
  double gain_sigma = 0.0;              // ...log-normal with this sigma (exposure/irradiance changes)
  double noise_probability = 0.0;       // add Gaussian noise...
  double noise_sigma_dn = 0.0;          // ...with sigma drawn uniformly up to this
  double threshold_probability = 0.0;   // raise the threshold...
  double threshold_max_fraction = 0.0;  // ...by up to this fraction of the sample's peak
  double dropout_probability = 0.0;     // blank a random disk (debris)...
  double dropout_max_radius_px = 0.0;   // ...of up to this radius on a random active pixel

  bool enabled() const {
    return gain_probability > 0 || noise_probability > 0 || threshold_probability > 0 || dropout_probability > 0;
  }
};

// Sets one field by its name ("gain_probability", "noise_sigma_dn", ...).
// Throws std::invalid_argument naming an unknown key or a bad value.
void setAugmentation(AugmentationConfig& config, const std::string& key, double value);
// "key=value" form of setAugmentation.
void setAugmentation(AugmentationConfig& config, const std::string& assignment);

// An augmented copy of `sample` (never empty: when augmentation would remove
// every pixel the sample is returned unchanged). Deterministic for a seed.
SparseSample augment(const SparseSample& sample, const InputSpec& spec, const AugmentationConfig& config,
                     std::uint64_t seed);

}  // namespace dss
