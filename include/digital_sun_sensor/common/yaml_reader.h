// The package's YAML reading rules, in one place: every problem is reported as
// "<file>: <key.path>: what", and a key the reader never asked for is an error
// ("unknown key"), so that a misspelt optional key or a --set typo is refused
// instead of silently falling back to a default.
//
// YamlReader walks a mapping and records every key path it looks at; after
// parsing, rejectUnknownKeys() names the first key of the document nobody
// looked at (sensor configs). unknownKeyIn() is the same rule for formats the
// package writes itself (calibration files, model metadata): the keys the
// writer emits for the parsed value are the known ones.
#pragma once

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <memory>
#include <set>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

namespace dss {

class YamlError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

class YamlReader {
 public:
  // The document's root mapping; `origin` names it in errors (a file path).
  YamlReader(const YAML::Node& root, std::string origin);

  [[noreturn]] void fail(const std::string& key, const std::string& what) const;

  // Whether the key is present and not null (also marks it as known).
  bool has(const std::string& key) const;
  // A nested mapping; an absent optional one reads as empty.
  YamlReader child(const std::string& key, bool required = true) const;
  // Item `index` of the list under `key` (which must be a mapping).
  YamlReader item(const std::string& key, std::size_t index) const;

  template <typename T>
  T get(const std::string& key) const {
    if (!has(key)) fail(key, "missing required key");
    return convert<T>(node_[key], key);
  }
  template <typename T>
  T get(const std::string& key, const T& fallback) const {
    return has(key) ? convert<T>(node_[key], key) : fallback;
  }
  double positive(const std::string& key) const;
  double positive(const std::string& key, double fallback) const;
  double nonNegative(const std::string& key, double fallback) const;
  double fraction(const std::string& key, double fallback) const;
  std::vector<double> positiveList(const std::string& key) const;

  const YAML::Node& node() const { return node_; }
  const std::string& origin() const { return origin_; }
  std::string join(const std::string& key) const { return path_.empty() ? key : path_ + "." + key; }

  // Fails on the first key of the whole document that no reader of it asked for.
  void rejectUnknownKeys() const;

 private:
  YamlReader(const YAML::Node& node, std::string origin, std::string path, std::shared_ptr<std::set<std::string>> seen);

  template <typename T>
  T convert(const YAML::Node& n, const std::string& key) const {
    try {
      T v = n.as<T>();
      if constexpr (std::is_floating_point_v<T>) {
        if (!std::isfinite(v)) fail(key, "must be finite");
      }
      return v;
    } catch (const YAML::Exception&) {
      fail(key, std::string("wrong type: expected ") + typeName<T>() + ", got '" + YAML::Dump(n) + "'");
    }
  }
  template <typename T>
  static const char* typeName() {
    if constexpr (std::is_same_v<T, bool>) return "a boolean";
    if constexpr (std::is_integral_v<T>) return "an integer";
    if constexpr (std::is_floating_point_v<T>) return "a number";
    return "a string";
  }
  double checkPositive(const std::string& key, double v) const;

  YAML::Node node_;
  std::string origin_;
  std::string path_;
  std::shared_ptr<std::set<std::string>> seen_;  // key paths asked for, shared by the whole document
};

// YAML::Load with the package's bounds: at most limits::kMaxYamlFileBytes of
// text and limits::kMaxYamlNodes nodes with every alias counted at the size
// of what it repeats (a "billion laughs" document is refused before it is
// built or walked). Throws YamlError "<origin>: ..." naming the limit; a
// syntax error is YAML::ParserException as from YAML::Load.
YAML::Node loadYaml(const std::string& text, const std::string& origin);

// The first key path in `given` that `known` lacks, with the keys known there
// ("angle_correction.degre: unknown key (known here: alpha, beta, degree)");
// maps are compared key by key, lists item by item. Empty when there is none.
std::string unknownKeyIn(const YAML::Node& given, const YAML::Node& known);

}  // namespace dss
