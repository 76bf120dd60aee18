#include "digital_sun_sensor/sim/readout.h"

#include <algorithm>
#include <cmath>

#include "digital_sun_sensor/common/vector_clones.h"

namespace dss {
namespace {

double normalCdf(double x) { return 0.5 * std::erfc(-x / std::sqrt(2.0)); }

}  // namespace

ReadoutTable::ReadoutTable(const DetectorNoiseConfig& noise) {
  const int max_code = (1 << noise.bit_depth) - 1;
  const double gain = max_code / noise.adc_full_scale_e;
  const double sigma = noise.read_noise_e;
  const int n_max = static_cast<int>(std::floor(noise.full_well_e));
  first_code_.resize(n_max + 1);
  cdf_offset_.resize(n_max + 1);
  cdf_length_.resize(n_max + 1);
  for (int n = 0; n <= n_max; ++n) {
    // code = clamp(floor((n + sigma z) gain + black + 0.5), 0, max)
    const double centre = n * gain + noise.black_level_dn;
    const double spread = 8.0 * sigma * gain + 1.0;
    const int lo = std::clamp(static_cast<int>(std::floor(centre - spread)), 0, max_code);
    const int hi = std::clamp(static_cast<int>(std::ceil(centre + spread)), 0, max_code);
    first_code_[n] = lo;
    cdf_offset_[n] = static_cast<int>(cdf_.size());
    for (int d = lo; d <= hi; ++d) {
      double p_le;
      if (d == max_code) {
        p_le = 1.0;
      } else if (sigma > 0.0) {
        // code <= d  <=>  (n + sigma z) gain + black + 0.5 < d + 1
        p_le = normalCdf(((d + 0.5 - noise.black_level_dn) / gain - n) / sigma);
      } else {
        p_le = centre + 0.5 < d + 1 ? 1.0 : 0.0;
      }
      cdf_.push_back(d == hi ? 1.0 : p_le);
    }
    cdf_length_[n] = hi - lo + 1;
  }
  // Mode of n = 0 and the probability of anything else.
  double best = -1.0;
  for (int i = 0; i < cdf_length_[0]; ++i) {
    const double p = cdf_[i] - (i > 0 ? cdf_[i - 1] : 0.0);
    if (p > best) best = p, zero_mode_ = first_code_[0] + i;
  }
  zero_exception_ = std::max(0.0, 1.0 - best);
}

int ReadoutTable::codeFor(int n, double u) const {
  const double* cdf = &cdf_[cdf_offset_[n]];
  const int len = cdf_length_[n];
  const int i = static_cast<int>(std::lower_bound(cdf, cdf + len, u) - cdf);
  return first_code_[n] + std::min(i, len - 1);
}

int ReadoutTable::sample(int n, Rng& rng) const {
  n = std::clamp(n, 0, static_cast<int>(first_code_.size()) - 1);
  return codeFor(n, rng.uniform());
}

int ReadoutTable::sampleZeroException(Rng& rng) const {
  // Inverse-CDF draw restricted to the codes other than the mode.
  const int mode_index = zero_mode_ - first_code_[0];
  const double below = mode_index > 0 ? cdf_[mode_index - 1] : 0.0;
  const double mode_cdf = cdf_[mode_index];
  const double tail = below + (1.0 - mode_cdf);
  if (tail <= 0.0) return zero_mode_;
  const double u = rng.uniform() * tail;
  return codeFor(0, u < below ? u : mode_cdf + (u - below) + 1e-300);
}

NoiseFreeReadout::NoiseFreeReadout(const SensorConfig& config, bool threshold)
    : max_code_(config.maxCode()),
      gain_(config.maxCode() / config.noise.adc_full_scale_e),
      black_dn_(config.noise.black_level_dn) {
  // On-chip thresholding through a lookup table over codes.
  table_.resize(static_cast<std::size_t>(max_code_) + 1);
  const bool on = threshold && config.threshold.enabled;
  const double level = config.threshold.level_fraction * max_code_;
  for (int d = 0; d <= max_code_; ++d) {
    table_[d] = d;
    if (!on) continue;
    if (d < level) {
      table_[d] = 0;
    } else if (config.threshold.rescale) {
      table_[d] = static_cast<int>(std::floor((d - level) / (max_code_ - level) * max_code_ + 0.5));
    }
  }
}

DSS_VECTOR_CLONES
void NoiseFreeReadout::codes(const float* rate, float scale, double clip_e, int count, std::uint16_t* out) const {
  const int* table = table_.data();
  for (int i = 0; i < count; ++i)
    out[i] = static_cast<std::uint16_t>(table[adcCode(std::min<double>(rate[i] * scale, clip_e))]);
}

int NoiseFreeReadout::unlitCode(double dark_e) const { return code(dark_e); }

double NoiseFreeReadout::unlitBelowE(double dark_e) const {
  const int unlit_dn = adcCode(dark_e);
  int top_unlit = -1;
  while (top_unlit < max_code_ && table_[top_unlit + 1] == table_[unlit_dn]) ++top_unlit;
  return top_unlit >= unlit_dn ? ((top_unlit + 0.5 - black_dn_) / gain_ - dark_e) * (1.0 - 1e-9) : 0.0;
}

}  // namespace dss
