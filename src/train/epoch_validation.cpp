// Validation after each epoch, and the best weights it keeps.
#include <yaml-cpp/yaml.h>

#include <algorithm>

#include "digital_sun_sensor/train/validation_error.h"
#include "trainer_impl.h"

namespace dss {

std::string validationYaml(const TrainProgress& p) {
  YAML::Emitter v;
  v << YAML::BeginMap;
  v << YAML::Key << "validation_alpha_mean_deg" << YAML::Value << p.val_alpha_mean_deg;
  v << YAML::Key << "validation_beta_mean_deg" << YAML::Value << p.val_beta_mean_deg;
  v << YAML::Key << "validation_alpha_max_deg" << YAML::Value << p.val_alpha_max_deg;
  v << YAML::Key << "validation_beta_max_deg" << YAML::Value << p.val_beta_max_deg;
  v << YAML::Key << "validation_class_accuracy" << YAML::Value << p.val_class_accuracy;
  v << YAML::Key << "validation_gross" << YAML::Value << p.val_gross;
  v << YAML::EndMap;
  return v.c_str();
}

void readValidationYaml(const YAML::Node& map, TrainProgress& p) {
  p.val_alpha_mean_deg = map["validation_alpha_mean_deg"].as<double>();
  p.val_beta_mean_deg = map["validation_beta_mean_deg"].as<double>();
  p.val_alpha_max_deg = map["validation_alpha_max_deg"].as<double>();
  p.val_beta_max_deg = map["validation_beta_max_deg"].as<double>();
  p.val_class_accuracy = map["validation_class_accuracy"].as<double>();
  p.val_gross = map["validation_gross"].as<std::int64_t>();
}

// Fills the val_* fields of `out` from (at most validation_max) validation samples.
void Trainer::Impl::measure(TrainProgress& out) {
  if (validation.size() == 0) return;
  model.net->eval();
  torch::NoGradGuard no_grad;
  const std::size_t n = std::min(validation.size(), options.validation_max);
  const double stride = static_cast<double>(validation.size()) / static_cast<double>(n);
  std::vector<const SparseSample*> picked;
  for (std::size_t i = 0; i < n; ++i)
    picked.push_back(&validation.samples()[static_cast<std::size_t>(static_cast<double>(i) * stride)]);
  const ValidationError v = summarizeValidation(picked, model.predictSamples(picked));
  model.net->train();
  out.val_alpha_mean_deg = v.alpha_mean_deg;
  out.val_beta_mean_deg = v.beta_mean_deg;
  out.val_alpha_max_deg = v.alpha_max_deg;
  out.val_beta_max_deg = v.beta_max_deg;
  out.val_class_accuracy = v.class_accuracy;
  out.val_gross = static_cast<std::int64_t>(v.gross);
}

void Trainer::Impl::validate() {
  last.epoch_end = true;
  if (validation.size() == 0) return;
  measure(last);
  const double mean = 0.5 * (last.val_alpha_mean_deg + last.val_beta_mean_deg);
  if (best_epoch < 0 || mean < best_val_mean_deg) {
    best_val_mean_deg = mean;
    best_epoch = last.epoch;
    best_model_bytes = serializeModel(withMetadata(""));
  }
  last.best_val_mean_deg = best_val_mean_deg;
  last.best_epoch = best_epoch;
}

}  // namespace dss
