#include "digital_sun_sensor/model/unit_recalibration.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <vector>

#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/model/model.h"

namespace dss {

void RecalibrationOptions::validate() const {
  auto fail = [](const std::string& what) { throw std::invalid_argument("recalibration: " + what); };
  if (window < 10) fail("window must be at least 10 pairs");
  if (min_pairs < 10 || min_pairs > window) fail("min_pairs must lie between 10 and the window");
  if (refit_every < 1) fail("refit_every must be at least 1");
  if (!(min_spread_deg >= 0.0)) fail("min_spread_deg must be >= 0");
  if (!(max_disagreement_deg > 0.0)) fail("max_disagreement_deg must be positive");
}

UnitRecalibrator::UnitRecalibrator(RecalibrationOptions options) : options_(std::move(options)) { options_.validate(); }

bool UnitRecalibrator::add(UnitImage image, double estimate_alpha_rad, double estimate_beta_rad) {
  const double disagreement =
      std::max(std::abs(image.alpha_rad - estimate_alpha_rad), std::abs(image.beta_rad - estimate_beta_rad));
  if (!(radToDeg(disagreement) <= options_.max_disagreement_deg) || image.site_um.empty()) {
    ++refused_;
    return false;
  }
  window_.push_back(std::move(image));
  if (window_.size() > options_.window) window_.pop_front();
  ++since_refit_;
  return true;
}

double UnitRecalibrator::spreadDeg() const {
  if (window_.size() < 2) return 0.0;
  double sa = 0.0, sb = 0.0, saa = 0.0, sbb = 0.0;
  for (const auto& u : window_) {
    sa += u.alpha_rad;
    sb += u.beta_rad;
    saa += u.alpha_rad * u.alpha_rad;
    sbb += u.beta_rad * u.beta_rad;
  }
  const auto n = static_cast<double>(window_.size());
  const double var_a = std::max(0.0, saa / n - (sa / n) * (sa / n));
  const double var_b = std::max(0.0, sbb / n - (sb / n) * (sb / n));
  return radToDeg(std::sqrt(std::min(var_a, var_b)));
}

bool UnitRecalibrator::due() const {
  const bool first = refits_ == 0;
  return window_.size() >= options_.min_pairs && spreadDeg() >= options_.min_spread_deg &&
         (first || since_refit_ >= options_.refit_every);
}

UnitCalibrationReport UnitRecalibrator::refit(Model& model) {
  const std::vector<UnitImage> images(window_.begin(), window_.end());
  since_refit_ = 0;
  last_ = fitUnitGeometry(model, images, options_.fit);
  ++refits_;
  return *last_;
}

}  // namespace dss
