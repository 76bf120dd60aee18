#include "digital_sun_sensor/train/value_saturation_choice.h"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <stdexcept>
#include <string>

#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/model/sscnn.h"

namespace dss {
namespace {

// A later candidate must lower the best cross-validated RMS by more than this
// fraction to be chosen (as calibrateBias's degrees: noise in the choice).
constexpr double kRequiredGain = 0.01;

void setValueSaturation(Model& model, double saturation) {
  model.meta.arch.value_saturation = saturation;
  model.net->setValueSaturation(saturation);
}

}  // namespace

const std::vector<double>& valueSaturationCandidates() {
  static const std::vector<double> candidates{0.0, 0.5, 1.0, 2.0};
  return candidates;
}

ValueSaturationChoice chooseValueSaturation(Model& model, const TrainingSet& data, std::size_t max_samples,
                                            int max_degree, const std::vector<double>& candidates) {
  if (!model.meta.arch.geometric_head)
    throw std::invalid_argument("value saturation choice: the model has no geometric head");
  if (candidates.empty()) throw std::invalid_argument("value saturation choice: no candidates");
  for (const double s : candidates)
    if (!(s >= 0.0) || !std::isfinite(s))
      throw std::invalid_argument("value saturation choice: candidate " + std::to_string(s) +
                                  " is not finite and >= 0");
  ValueSaturationChoice choice;
  choice.candidates = candidates;
  ModelMetadata best_meta;
  double best_rms = 0.0;
  const std::string metrics_before = model.meta.metrics_yaml;
  for (std::size_t k = 0; k < candidates.size(); ++k) {
    setValueSaturation(model, candidates[k]);
    model.meta.metrics_yaml = metrics_before;
    const BiasCalibration c = calibrateBias(model, data, max_samples, max_degree);
    const double rms = c.cross_validated_rms_deg[static_cast<std::size_t>(c.degree + 1)];
    choice.cross_validated_rms_deg.push_back(rms);
    if (k == 0 || rms < best_rms * (1.0 - kRequiredGain)) {
      best_rms = rms;
      choice.chosen = candidates[k];
      choice.correction = c;
      best_meta = model.meta;  // with the correction and metrics calibrateBias wrote
    }
  }
  model.meta = best_meta;
  setValueSaturation(model, choice.chosen);
  YAML::Node metrics = YAML::Load(model.meta.metrics_yaml);
  for (std::size_t k = 0; k < candidates.size(); ++k)
    metrics["value_saturation_cv_rms_deg"][candidates[k]] = choice.cross_validated_rms_deg[k];
  metrics["value_saturation"] = choice.chosen;
  model.meta.metrics_yaml = YAML::Dump(metrics);
  return choice;
}

}  // namespace dss
