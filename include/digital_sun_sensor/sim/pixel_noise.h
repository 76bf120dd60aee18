// The detector's per-pixel noise as a variance law (EMVA 1288, the Gaussian
// approximation): for a mean signal of mu electrons,
//   var = mu (shot) + dark + read^2 + step^2 / 12 (quantisation) + (PRNU mu)^2,
// and the same in the units of the image the sensor delivers (its codes, or
// after an on-chip threshold that rescales [level, top] onto [0, top], the
// rescaled values: the threshold stretches every code step).
#pragma once

#include "digital_sun_sensor/sim/sensor_config.h"

namespace dss {

class PixelNoise {
 public:
  // Dark electrons of an exposure of `exposure_s` (0: none) enter every pixel.
  explicit PixelNoise(const SensorConfig& config, double exposure_s = 0.0);

  // [e^2] for a mean signal [e] (optical, before dark current).
  double varianceE2(double mean_e) const;
  // [image value^2] for a mean image value (a pixel the threshold censors
  // reads the variance at the threshold).
  double varianceOfValue(double value) const;
  // Whether a pixel of this mean value lies `sigmas` noise deviations inside
  // the readout's linear range (above the threshold or black clip, below the
  // top code): there its variance above holds; near either end the clipping
  // narrows it.
  bool inLinearRange(double value, double sigmas) const;

 private:
  double constant_e2_ = 0.0;  // read noise, quantisation and dark electrons
  double prnu_fraction_ = 0.0;
  double e_per_code_ = 1.0;
  double black_dn_ = 0.0;
  double level_code_ = 0.0;                      // threshold (0: none)
  double value_per_code_ = 1.0;                  // the threshold's rescaling
  double lowest_value_ = 0.0, top_value_ = 0.0;  // the linear range of the delivered values
};

}  // namespace dss
