// In-flight recalibration of a unit: images paired with a reference sun
// direction (a star tracker and an ephemeris) collected in a bounded window,
// and the geometric head's geometry refitted from them (fitUnitGeometry)
// once they span enough of the field. References far from the model's own
// estimate are refused before they enter; spots that disagree with the fit
// are dropped by it. Torch-free header.
#pragma once

#include <cstddef>
#include <deque>
#include <optional>
#include <string>

#include "digital_sun_sensor/model/unit_calibration.h"

namespace dss {

struct RecalibrationOptions {
  std::size_t window = 400;           // pairs kept (the oldest go first)
  std::size_t min_pairs = 50;         // before the first refit
  std::size_t refit_every = 25;       // new pairs between refits
  double min_spread_deg = 2.0;        // standard deviation of the references' alpha and of beta, each at least this
  double max_disagreement_deg = 1.0;  // a reference farther than this from the estimate is refused
  UnitCalibrationOptions fit;

  // Throws std::invalid_argument naming the first bad value.
  void validate() const;
};

class UnitRecalibrator {
 public:
  explicit UnitRecalibrator(RecalibrationOptions options);

  // Offers one image with its reference angles and the model's estimate of
  // them [rad]; false (and counted) when the two disagree by more than
  // max_disagreement_deg.
  bool add(UnitImage image, double estimate_alpha_rad, double estimate_beta_rad);
  // Enough pairs, spread over the field, and refit_every new ones since the last refit.
  bool due() const;
  // Refits the model's geometry from the window (from its current values).
  // Throws std::invalid_argument when the fit cannot be made (the model is
  // then unchanged).
  UnitCalibrationReport refit(Model& model);

  std::size_t pairs() const { return window_.size(); }
  std::size_t refused() const { return refused_; }
  std::size_t refits() const { return refits_; }
  // Standard deviation of the window's references, the smaller axis [deg].
  double spreadDeg() const;
  const std::optional<UnitCalibrationReport>& last() const { return last_; }

 private:
  RecalibrationOptions options_;
  std::deque<UnitImage> window_;
  std::size_t since_refit_ = 0, refused_ = 0, refits_ = 0;
  std::optional<UnitCalibrationReport> last_;
};

}  // namespace dss
