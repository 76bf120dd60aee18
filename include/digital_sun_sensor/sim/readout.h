// Exact, fast detector readout. With shot noise on, each pixel holds an
// integer electron count n before read noise, so the output code's
// distribution depends on n alone: P(DN = d | n) from read noise, gain, black
// level, rounding and ADC clipping. We tabulate those distributions once and
// draw each pixel's code with one uniform; pixels with n = 0 (nearly all of a
// sun sensor image) keep the most likely code, and the rare exceptions are
// found by geometric skipping. Same distribution as per-pixel Gaussian draws,
// at a fraction of the cost.
#pragma once

#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/sim/sensor_config.h"

#include <vector>

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

  std::vector<int> first_code_;    // per n
  std::vector<int> cdf_offset_;    // per n, into cdf_
  std::vector<int> cdf_length_;    // per n
  std::vector<double> cdf_;
  int zero_mode_ = 0;
  double zero_exception_ = 0.0;
};

}  // namespace dss
