// The predicted sigma's level, set through the network's variance head
// (SscnnNetImpl::shiftLogVariance and friends), never by parameter name.
#include <cmath>
#include <stdexcept>

#include "digital_sun_sensor/model/model.h"

namespace dss {

void Model::scaleSigma(double alpha_factor, double beta_factor) {
  if (!(alpha_factor > 0.0 && beta_factor > 0.0 && std::isfinite(alpha_factor) && std::isfinite(beta_factor)))
    throw std::invalid_argument("scaleSigma: factors must be finite and positive");
  // log variance + 2 log f = log (f sigma)^2
  net->shiftLogVariance(2.0 * std::log(alpha_factor), 2.0 * std::log(beta_factor));
}

void Model::setConstantSigma(double alpha_sigma_rad, double beta_sigma_rad) {
  if (!(alpha_sigma_rad > 0.0 && beta_sigma_rad > 0.0 && std::isfinite(alpha_sigma_rad) &&
        std::isfinite(beta_sigma_rad)))
    throw std::invalid_argument("setConstantSigma: sigmas must be finite and positive");
  const double s = meta.angle_scale_rad;
  // log variance of the normalized angle
  net->setConstantLogVariance(2.0 * std::log(alpha_sigma_rad / s), 2.0 * std::log(beta_sigma_rad / s));
}

std::optional<std::array<double, 2>> Model::constantSigma() const {
  const auto log_variance = net->constantLogVariance();
  if (!log_variance) return std::nullopt;
  const double s = meta.angle_scale_rad;
  return std::array<double, 2>{s * std::exp(0.5 * (*log_variance)[0]), s * std::exp(0.5 * (*log_variance)[1])};
}

}  // namespace dss
