#include "digital_sun_sensor/train/validation_error.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/model/sscnn_estimator.h"

namespace dss {

ValidationError summarizeValidation(const std::vector<const SparseSample*>& samples,
                                    const std::vector<Prediction>& predictions) {
  if (samples.size() != predictions.size())
    throw std::invalid_argument("summarizeValidation: " + std::to_string(predictions.size()) + " predictions for " +
                                std::to_string(samples.size()) + " samples");
  ValidationError v;
  v.images = samples.size();
  if (v.images == 0) return v;
  double sum_a = 0, sum_b = 0;
  std::size_t correct = 0;
  for (std::size_t k = 0; k < samples.size(); ++k) {
    const Prediction& p = predictions[k];
    const SparseSample& s = *samples[k];
    const bool right_class = p.subfov_class == std::max(0, s.subfov_class);
    correct += right_class;
    const double ea = std::abs(p.alpha_rad - s.alpha_rad) * kDegPerRad;
    const double eb = std::abs(p.beta_rad - s.beta_rad) * kDegPerRad;
    if (p.code_margin < kMinApertureCodeMargin || p.lone_spot_ambiguous || !p.declined.empty() ||
        (!right_class && std::max(ea, eb) > kGrossValidationErrorDeg)) {
      ++v.gross;
      continue;
    }
    sum_a += ea;
    sum_b += eb;
    v.alpha_max_deg = std::max(v.alpha_max_deg, ea);
    v.beta_max_deg = std::max(v.beta_max_deg, eb);
  }
  const std::size_t kept = v.images - v.gross;
  // With every image left out there is nothing to rank an epoch by: worst.
  v.alpha_mean_deg = kept > 0 ? sum_a / static_cast<double>(kept) : std::numeric_limits<double>::infinity();
  v.beta_mean_deg = kept > 0 ? sum_b / static_cast<double>(kept) : std::numeric_limits<double>::infinity();
  v.class_accuracy = static_cast<double>(correct) / static_cast<double>(v.images);
  return v;
}

}  // namespace dss
