#include "digital_sun_sensor/sim/pixel_noise.h"

#include <algorithm>
#include <cmath>

namespace dss {

PixelNoise::PixelNoise(const SensorConfig& config, double exposure_s) {
  const auto& n = config.noise;
  const double top = config.maxCode();
  e_per_code_ = n.adc_full_scale_e / top;
  constant_e2_ = n.read_noise_e * n.read_noise_e + e_per_code_ * e_per_code_ / 12.0 +
                 n.darkCurrentAtTemperatureEPerS() * std::max(exposure_s, 0.0);
  prnu_fraction_ = n.prnu_fraction;
  black_dn_ = n.black_level_dn;
  if (config.threshold.enabled) {
    level_code_ = config.threshold.level_fraction * top;
    if (config.threshold.rescale && top > level_code_)
      value_per_code_ = top / (top - level_code_);
    else
      lowest_value_ = level_code_;
  }
  top_value_ = top;
}

bool PixelNoise::inLinearRange(double value, double sigmas) const {
  const double sd = sigmas * std::sqrt(varianceOfValue(value));
  return value - sd > lowest_value_ && value + sd < top_value_;
}

double PixelNoise::varianceE2(double mean_e) const {
  mean_e = std::max(mean_e, 0.0);
  return mean_e + constant_e2_ + prnu_fraction_ * prnu_fraction_ * mean_e * mean_e;
}

double PixelNoise::varianceOfValue(double value) const {
  // Back to the code (a rescaled value v of code d: v = (d - level) * value_per_code).
  const double code = value_per_code_ != 1.0 ? value / value_per_code_ + level_code_ : std::max(value, level_code_);
  const double mean_e = (code - black_dn_) * e_per_code_;
  const double code_variance = varianceE2(mean_e) / (e_per_code_ * e_per_code_);
  return code_variance * value_per_code_ * value_per_code_;
}

}  // namespace dss
