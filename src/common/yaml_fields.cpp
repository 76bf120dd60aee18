#include "digital_sun_sensor/common/yaml_fields.h"

#include <charconv>

namespace dss {

std::string listChoices(const std::vector<std::string>& names) {
  std::string out;
  for (std::size_t i = 0; i < names.size(); ++i) {
    if (i > 0) out += i + 1 == names.size() ? " or " : ", ";
    out += names[i];
  }
  return out;
}

std::string shortestDecimal(double value) {
  char buffer[32];
  const auto result = std::to_chars(buffer, buffer + sizeof(buffer), value);
  return std::string(buffer, result.ptr);
}

void YamlFieldReader::number(const std::string& key, double& value, Bound bound, Required) {
  if (!top().has(key)) top().fail(key, "missing required key");
  number(key, value, bound, 0.0);
}

void YamlFieldReader::number(const std::string& key, double& value, Bound bound, double fallback) {
  switch (bound) {
    case Bound::kAny:
      value = top().get<double>(key, fallback);
      break;
    case Bound::kPositive:
      value = top().positive(key, fallback);
      break;
    case Bound::kNonNegative:
      value = top().nonNegative(key, fallback);
      break;
    case Bound::kFraction:
      value = top().fraction(key, fallback);
      break;
  }
}

void YamlFieldReader::integer(const std::string& key, int& value, long long lo, long long hi,
                              const std::string& range) {
  value = top().get<int>(key, value);
  if (value < lo || value > hi) top().fail(key, range);
}

void YamlFieldReader::integer(const std::string& key, int& value, long long lo, long long hi, const std::string& range,
                              Required) {
  if (!top().has(key)) top().fail(key, "missing required key");
  integer(key, value, lo, hi, range);
}

std::size_t YamlFieldReader::checkItems(const std::string& key, std::size_t max_items, const char* noun) const {
  if (!top().has(key)) top().fail(key, "missing required key");
  const YAML::Node& list = top().node()[key];
  if (!list.IsSequence() || list.size() == 0) top().fail(key, std::string("expected a non-empty list of ") + noun);
  if (list.size() > max_items)
    top().fail(key, std::to_string(list.size()) + " " + noun + ", over the limit of " + std::to_string(max_items));
  return list.size();
}

}  // namespace dss
