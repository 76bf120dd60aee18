#include "digital_sun_sensor/model/input_envelope.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>

namespace dss {

InputEnvelope measureInputEnvelope(std::vector<int> site_counts) {
  InputEnvelope e;
  if (site_counts.empty()) return e;
  std::sort(site_counts.begin(), site_counts.end());
  auto quantile = [&](double q) {
    return site_counts[static_cast<std::size_t>(std::lround(q * static_cast<double>(site_counts.size() - 1)))];
  };
  // The widening keeps the false alarms on nominal images near zero: the
  // quantiles of a few thousand images are themselves uncertain by ~10 %.
  e.min_sites = static_cast<int>(std::floor(quantile(0.001) / 1.25));
  e.max_sites = std::max(1, static_cast<int>(std::ceil(quantile(0.999) * 1.25)));
  return e;
}

InputEnvelope inputEnvelopeOf(const ModelMetadata& meta) {
  InputEnvelope e;
  try {
    const YAML::Node metrics = YAML::Load(meta.metrics_yaml);
    if (metrics["lit_sites_min"] && metrics["lit_sites_max"]) {
      e.min_sites = metrics["lit_sites_min"].as<int>();
      e.max_sites = metrics["lit_sites_max"].as<int>();
    }
  } catch (const YAML::Exception&) {
    return {};  // metrics are informational; a model without a readable envelope is checked without one
  }
  if (e.min_sites < 0 || e.max_sites < e.min_sites) return {};
  return e;
}

InputEnvelope covering(const InputEnvelope& a, const InputEnvelope& b) {
  if (!a.known()) return b;
  if (!b.known()) return a;
  return {std::min(a.min_sites, b.min_sites), std::max(a.max_sites, b.max_sites)};
}

void recordInputEnvelope(ModelMetadata& meta, const InputEnvelope& envelope) {
  YAML::Node metrics = YAML::Load(meta.metrics_yaml.empty() ? "{}" : meta.metrics_yaml);
  metrics["lit_sites_min"] = envelope.min_sites;
  metrics["lit_sites_max"] = envelope.max_sites;
  meta.metrics_yaml = YAML::Dump(metrics);
}

}  // namespace dss
