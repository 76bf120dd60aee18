#include "digital_sun_sensor/eval/evaluation.h"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <sstream>

#include "digital_sun_sensor/common/file_io.h"
#include "digital_sun_sensor/common/json.h"
#include "digital_sun_sensor/common/units.h"

namespace dss {
namespace {

AxisStats axisStats(std::vector<double> errors_deg) {
  AxisStats s;
  if (errors_deg.empty()) return s;
  double sum = 0.0, sum_sq = 0.0;
  for (double e : errors_deg) sum += e, sum_sq += e * e;
  s.mean_deg = sum / errors_deg.size();
  s.rms_deg = std::sqrt(sum_sq / errors_deg.size());
  std::sort(errors_deg.begin(), errors_deg.end());
  const std::size_t p99 = static_cast<std::size_t>(std::ceil(0.99 * errors_deg.size())) - 1;
  s.p99_deg = errors_deg[std::min(p99, errors_deg.size() - 1)];
  s.max_deg = errors_deg.back();
  return s;
}

using json::number;
using json::quoted;

std::string csvField(std::string s) {
  std::replace(s.begin(), s.end(), ',', ';');
  std::replace(s.begin(), s.end(), '\n', ' ');
  return s;
}

}  // namespace

EvalSummary summarize(const std::vector<EvalRecord>& records, const std::string& estimator, double total_ms) {
  EvalSummary s;
  s.estimator = estimator;
  s.n = records.size();
  std::vector<double> ea, eb;
  std::vector<ErrorAndSigma> za, zb;
  std::size_t class_known = 0, class_right = 0;
  double err_sq = 0.0, bound_sq = 0.0, readout_err_sq = 0.0, readout_bound_sq = 0.0;
  std::size_t readout_samples = 0;
  for (const auto& r : records) {
    if (!r.estimate.valid) continue;
    ++s.valid;
    const double a = std::abs(r.estimate.alpha_rad - r.alpha_true_rad),
                 b = std::abs(r.estimate.beta_rad - r.beta_true_rad);
    ea.push_back(a * kDegPerRad);
    eb.push_back(b * kDegPerRad);
    za.push_back({a, std::sqrt(r.estimate.covariance[0])});
    zb.push_back({b, std::sqrt(r.estimate.covariance[3])});
    if (r.subfov_true >= 0) {
      ++class_known;
      class_right += r.estimate.subfov_class == r.subfov_true;
    }
    if (std::isfinite(r.crlb_alpha_rad2) && std::isfinite(r.crlb_beta_rad2)) {
      ++s.crlb_samples;
      err_sq += a * a + b * b;
      bound_sq += r.crlb_alpha_rad2 + r.crlb_beta_rad2;
    }
    if (std::isfinite(r.readout_crlb_alpha_rad2) && std::isfinite(r.readout_crlb_beta_rad2)) {
      ++readout_samples;
      readout_err_sq += a * a + b * b;
      readout_bound_sq += r.readout_crlb_alpha_rad2 + r.readout_crlb_beta_rad2;
    }
  }
  s.alpha = axisStats(ea);
  s.beta = axisStats(eb);
  s.alpha_coverage = measureCoverage(za);
  s.beta_coverage = measureCoverage(zb);
  s.valid_rate = s.n ? static_cast<double>(s.valid) / s.n : 0.0;
  if (class_known) s.subfov_accuracy = static_cast<double>(class_right) / class_known;
  s.ms_per_image = s.n ? total_ms / s.n : 0.0;
  if (s.crlb_samples && bound_sq > 0.0) {
    s.crlb_ratio = std::sqrt(err_sq / bound_sq);
    s.crlb_rms_deg = std::sqrt(bound_sq / (2.0 * s.crlb_samples)) * kDegPerRad;
  }
  if (readout_samples && readout_bound_sq > 0.0) {
    s.readout_crlb_ratio = std::sqrt(readout_err_sq / readout_bound_sq);
    s.readout_crlb_rms_deg = std::sqrt(readout_bound_sq / (2.0 * readout_samples)) * kDegPerRad;
  }
  return s;
}

std::string EvalSummary::toJson() const {
  std::ostringstream os;
  os << "{\"estimator\": " << quoted(estimator) << ", \"n\": " << n;
  const std::pair<const char*, const AxisStats*> axes[] = {{"alpha", &alpha}, {"beta", &beta}};
  for (const auto& [name, st] : axes) {
    os << ", \"" << name << "_mean_deg\": " << number(valid ? st->mean_deg : NAN) << ", \"" << name
       << "_rms_deg\": " << number(valid ? st->rms_deg : NAN) << ", \"" << name
       << "_p99_deg\": " << number(valid ? st->p99_deg : NAN) << ", \"" << name
       << "_max_deg\": " << number(valid ? st->max_deg : NAN);
  }
  os << ", \"subfov_accuracy\": " << number(subfov_accuracy) << ", \"valid_rate\": " << number(valid_rate)
     << ", \"ms_per_image\": " << number(ms_per_image) << ", \"crlb_ratio\": " << number(crlb_ratio)
     << ", \"crlb_rms_deg\": " << number(crlb_rms_deg) << ", \"crlb_samples\": " << crlb_samples
     << ", \"readout_crlb_ratio\": " << number(readout_crlb_ratio)
     << ", \"readout_crlb_rms_deg\": " << number(readout_crlb_rms_deg);
  const std::pair<const char*, const Coverage*> coverages[] = {{"alpha", &alpha_coverage}, {"beta", &beta_coverage}};
  for (const auto& [name, c] : coverages) {
    for (int k = 0; k < 3; ++k)
      os << ", \"" << name << "_within_" << k + 1 << "sigma\": " << number(c->count ? c->within[k] : NAN);
  }
  os << "}";
  return os.str();
}

void writeEvalCsv(const std::string& path, const std::vector<EvalRecord>& records) {
  std::ostringstream os;
  os << std::setprecision(10);
  os << "index,stamp_s,alpha_true_deg,beta_true_deg,alpha_est_deg,beta_est_deg,alpha_error_deg,beta_error_deg,"
        "alpha_sigma_deg,beta_sigma_deg,valid,status,subfov_true,subfov_est,crlb_alpha_deg,crlb_beta_deg\n";
  for (const auto& r : records) {
    const auto& e = r.estimate;
    os << r.index << ',' << r.stamp_s << ',' << r.alpha_true_rad * kDegPerRad << ',' << r.beta_true_rad * kDegPerRad
       << ',' << e.alpha_rad * kDegPerRad << ',' << e.beta_rad * kDegPerRad << ','
       << (e.alpha_rad - r.alpha_true_rad) * kDegPerRad << ',' << (e.beta_rad - r.beta_true_rad) * kDegPerRad << ','
       << std::sqrt(std::max(0.0, e.covariance[0])) * kDegPerRad << ','
       << std::sqrt(std::max(0.0, e.covariance[3])) * kDegPerRad << ',' << (e.valid ? 1 : 0) << ','
       << csvField(e.status) << ',' << r.subfov_true << ',' << e.subfov_class << ','
       << std::sqrt(r.crlb_alpha_rad2) * kDegPerRad << ',' << std::sqrt(r.crlb_beta_rad2) * kDegPerRad << '\n';
  }
  writeFileAtomic(path, os.str());
}

}  // namespace dss
