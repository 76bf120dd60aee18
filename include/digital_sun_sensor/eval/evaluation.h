// Accuracy of an estimator against ground truth: per-axis error statistics
// over the images it marked valid, valid rate, sub-FOV accuracy, speed and the
// ratio to the Cramer-Rao bound. One JSON line (docs/design.md, "Evaluation keys") and a
// per-sample CSV.
#pragma once

#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "digital_sun_sensor/common/sun_estimate.h"
#include "digital_sun_sensor/eval/uncertainty.h"

namespace dss {

struct EvalRecord {
  std::uint64_t index = 0;
  double stamp_s = 0.0;
  double alpha_true_rad = 0.0;
  double beta_true_rad = 0.0;
  int subfov_true = -1;
  SunEstimate estimate;
  // Cramer-Rao bound variances [rad^2] where computed (NaN otherwise).
  double crlb_alpha_rad2 = std::numeric_limits<double>::quiet_NaN();
  double crlb_beta_rad2 = std::numeric_limits<double>::quiet_NaN();
  // The same for the readout as configured (on-chip threshold censoring).
  double readout_crlb_alpha_rad2 = std::numeric_limits<double>::quiet_NaN();
  double readout_crlb_beta_rad2 = std::numeric_limits<double>::quiet_NaN();
};

struct AxisStats {
  double mean_deg = 0.0, rms_deg = 0.0, p99_deg = 0.0, max_deg = 0.0;
};

struct EvalSummary {
  std::string estimator;
  std::size_t n = 0;
  std::size_t valid = 0;
  AxisStats alpha, beta;
  double subfov_accuracy = std::numeric_limits<double>::quiet_NaN();
  double valid_rate = 0.0;
  double ms_per_image = 0.0;
  // RMS error over the bound's RMS on the images where both exist (NaN: none).
  double crlb_ratio = std::numeric_limits<double>::quiet_NaN();
  double crlb_rms_deg = std::numeric_limits<double>::quiet_NaN();
  std::size_t crlb_samples = 0;
  // The same against the bound of the readout as configured.
  double readout_crlb_ratio = std::numeric_limits<double>::quiet_NaN();
  double readout_crlb_rms_deg = std::numeric_limits<double>::quiet_NaN();
  // Fraction of valid estimates whose error lies within 1 / 2 / 3 predicted sigma.
  Coverage alpha_coverage, beta_coverage;

  std::string toJson() const;  // one line, docs/design.md's evaluation keys first
};

EvalSummary summarize(const std::vector<EvalRecord>& records, const std::string& estimator, double total_ms);

// Per-sample CSV, written atomically.
void writeEvalCsv(const std::string& path, const std::vector<EvalRecord>& records);

}  // namespace dss
