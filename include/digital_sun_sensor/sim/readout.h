// Exact, fast detector readout. With shot noise on, each pixel holds an
// integer electron count n before read noise, so the output code's
// distribution depends on n alone: P(DN = d | n) from read noise, gain, black
// level, rounding and ADC clipping. We tabulate those distributions once and
// draw each pixel's code with one uniform; pixels with n = 0 (nearly all of a
// sun sensor image) keep the most likely code, and the rare exceptions are
// found by geometric skipping. Same distribution as per-pixel Gaussian draws,
// at a fraction of the cost.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/sim/sensor_config.h"

namespace dss {

class ReadoutTable {
 public:
  explicit ReadoutTable(const DetectorNoiseConfig& noise);

  // Code for electron count n (0 <= n <= full well), one uniform draw.
  int sample(int n, Rng& rng) const;
  // Most likely code for n = 0 and the probability of any other code.
  int zeroMode() const { return zero_mode_; }
  double zeroExceptionProbability() const { return zero_exception_; }
  // A code for n = 0 conditioned on differing from zeroMode().
  int sampleZeroException(Rng& rng) const;

 private:
  int codeFor(int n, double u) const;

  std::vector<int> first_code_;  // per n
  std::vector<int> cdf_offset_;  // per n, into cdf_
  std::vector<int> cdf_length_;  // per n
  std::vector<double> cdf_;
  int zero_mode_ = 0;
  double zero_exception_ = 0.0;
};

// The detector's readout without noise (RenderOptions::noise off, or no
// shot noise): a pixel's code for its electrons, through the on-chip
// threshold's table when `threshold` (and the config enables it).
class NoiseFreeReadout {
 public:
  NoiseFreeReadout(const SensorConfig& config, bool threshold);

  // The delivered code of `electrons` (dark ones and any read noise
  // included; the full well's clip is the caller's).
  int code(double electrons) const { return table_[static_cast<std::size_t>(adcCode(electrons))]; }
  // code(min(rate[i] * scale, clip_e)) into out[i], i < count (the product
  // in float), in a loop the compiler vectorises (the table read a gather).
  void codes(const float* rate, float scale, double clip_e, int count, std::uint16_t* out) const;
  // The code of a pixel holding `dark_e` alone; the signal below which a
  // pixel reads it too (the ADC codes that the threshold maps onto it: under
  // thesis_ca's 90 % threshold, most of the scale), 0 where none does.
  int unlitCode(double dark_e) const;
  double unlitBelowE(double dark_e) const;
  // The threshold's table over ADC codes (the identity without one).
  const std::vector<int>& table() const { return table_; }

 private:
  // The ADC code of `electrons`, rounded half up and clipped to [0, top]:
  // the value is first held within [-1, top + 1], where truncation (exact,
  // one instruction, vectorised) clips to the same code as floor() (a
  // library call without SSE4.1; this runs per lit pixel).
  int adcCode(double electrons) const {
    const double half_up = std::clamp(electrons * gain_ + black_dn_ + 0.5, -1.0, max_code_ + 1.0);
    return std::clamp(static_cast<int>(half_up), 0, max_code_);
  }

  std::vector<int> table_;
  int max_code_ = 0;
  double gain_ = 0.0;  // DN per electron
  double black_dn_ = 0.0;
};

}  // namespace dss
