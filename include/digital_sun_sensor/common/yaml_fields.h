// One table of keys for a YAML format, read and written from the same list.
//
// A format's keys are written once, as a function template over a visitor:
//
//   template <class Fields>
//   void detectorFields(Fields& f, DetectorConfig& d) {
//     f.integer("width_px", d.width_px, 8, 8192, "must be in [8, 8192]");
//     f.number("pitch_um", d.pitch_um, Bound::kPositive);
//   }
//
// YamlFieldReader fills each value from a document (required keys, defaults,
// bounds, the package's error wording "<file>: <key.path>: what", unknown keys
// refused); YamlFieldWriter emits the same keys in the same order. A key added
// to the table is therefore read, validated and written, or none of these.
#pragma once

#include <yaml-cpp/yaml.h>

#include <initializer_list>
#include <string>
#include <utility>
#include <vector>

#include "digital_sun_sensor/common/yaml_reader.h"

namespace dss {

enum class Bound { kAny, kPositive, kNonNegative, kFraction };  // kFraction: in [0, 1]
enum class Layout { kBlock, kFlow };                            // how the writer lays a mapping out
enum class Presence { kRequired, kOptional };                   // an absent optional section reads as defaults

// A key that must be given. Any other key is optional, and when absent keeps
// the value it had (the struct's default), unless a fallback is named.
struct Required {};
inline constexpr Required kRequired{};

template <typename E>
using ChoiceNames = std::initializer_list<std::pair<const char*, E>>;

// "a, b or c", for "expected ..." in errors.
std::string listChoices(const std::vector<std::string>& names);

// The shortest decimal that reads back as exactly `value` ("0.56", not
// yaml-cpp's "0.56000000000000005").
std::string shortestDecimal(double value);

class YamlFieldReader {
 public:
  explicit YamlFieldReader(const YamlReader& root) : stack_{root} {}

  void text(const std::string& key, std::string& value, Required) { value = top().get<std::string>(key); }
  void flag(const std::string& key, bool& value) { value = top().get<bool>(key, value); }
  void number(const std::string& key, double& value, Bound bound) { number(key, value, bound, value); }
  void number(const std::string& key, double& value, Bound bound, Required);
  void number(const std::string& key, double& value, Bound bound, double fallback);
  // An integer in [lo, hi]; `range` is the error's wording when it is not.
  void integer(const std::string& key, int& value, long long lo, long long hi, const std::string& range);
  void integer(const std::string& key, int& value, long long lo, long long hi, const std::string& range, Required);
  // A required, non-empty list of positive numbers.
  void numbers(const std::string& key, std::vector<double>& values) { values = top().positiveList(key); }

  // One of the named values; `what` names the kind in errors ("optics mode").
  template <typename E>
  void choice(const std::string& key, E& value, ChoiceNames<E> names, const char* what) {
    std::vector<std::string> all;
    for (const auto& n : names) all.emplace_back(n.first);
    const auto name = top().get<std::string>(key, nameOf(value, names));
    for (const auto& n : names) {
      if (name == n.first) {
        value = n.second;
        return;
      }
    }
    top().fail(key, "unknown " + std::string(what) + " '" + name + "' (expected " + listChoices(all) + ")");
  }

  template <typename Body>
  void section(const std::string& key, Layout, Presence presence, Body body) {
    stack_.push_back(top().child(key, presence == Presence::kRequired));
    body();
    stack_.pop_back();
  }

  // A required, non-empty list of at most `max_items` mappings; `noun` names
  // them in errors ("apertures").
  template <typename T, typename Body>
  void items(const std::string& key, std::vector<T>& list, std::size_t max_items, const char* noun, Layout, Body body) {
    const std::size_t n = checkItems(key, max_items, noun);
    list.clear();
    for (std::size_t i = 0; i < n; ++i) {
      stack_.push_back(top().item(key, i));
      T item{};
      body(item);
      list.push_back(std::move(item));
      stack_.pop_back();
    }
  }

  // A rule across keys; fails on `key` (a path below the current mapping) unless ok.
  void check(const std::string& key, bool ok, const std::string& what) const {
    if (!ok) top().fail(key, what);
  }

  // Fails on the first key of the document that the table does not name.
  void rejectUnknownKeys() const { stack_.front().rejectUnknownKeys(); }

 private:
  template <typename E>
  static std::string nameOf(const E& value, ChoiceNames<E> names) {
    for (const auto& n : names)
      if (n.second == value) return n.first;
    return "";
  }
  std::size_t checkItems(const std::string& key, std::size_t max_items, const char* noun) const;
  const YamlReader& top() const { return stack_.back(); }

  std::vector<YamlReader> stack_;  // the mapping being read, innermost last
};

class YamlFieldWriter {
 public:
  YamlFieldWriter() { out_ << YAML::BeginMap; }

  void text(const std::string& key, const std::string& value, Required) { put(key, value); }
  void flag(const std::string& key, bool value) { put(key, value); }
  template <typename... Rule>
  void number(const std::string& key, double value, Bound, Rule...) {
    put(key, shortestDecimal(value));
  }
  template <typename... Rule>
  void integer(const std::string& key, int value, long long, long long, const std::string&, Rule...) {
    put(key, value);
  }
  void numbers(const std::string& key, const std::vector<double>& values) {
    out_ << YAML::Key << key << YAML::Value << YAML::Flow << YAML::BeginSeq;
    for (double v : values) out_ << shortestDecimal(v);
    out_ << YAML::EndSeq;
  }
  template <typename E>
  void choice(const std::string& key, const E& value, ChoiceNames<E> names, const char*) {
    for (const auto& n : names) {
      if (n.second == value) {
        put(key, n.first);
        return;
      }
    }
  }
  template <typename Body>
  void section(const std::string& key, Layout layout, Presence, Body body) {
    out_ << YAML::Key << key << YAML::Value;
    if (layout == Layout::kFlow) out_ << YAML::Flow;
    out_ << YAML::BeginMap;
    body();
    out_ << YAML::EndMap;
  }
  template <typename T, typename Body>
  void items(const std::string& key, std::vector<T>& list, std::size_t, const char*, Layout layout, Body body) {
    out_ << YAML::Key << key << YAML::Value << YAML::BeginSeq;
    for (auto& item : list) {
      if (layout == Layout::kFlow) out_ << YAML::Flow;
      out_ << YAML::BeginMap;
      body(item);
      out_ << YAML::EndMap;
    }
    out_ << YAML::EndSeq;
  }
  void check(const std::string&, bool, const std::string&) const {}

  // The document written so far, closed.
  std::string str() {
    out_ << YAML::EndMap;
    return out_.c_str();
  }

 private:
  template <typename T>
  void put(const std::string& key, const T& value) {
    out_ << YAML::Key << key << YAML::Value << value;
  }
  YAML::Emitter out_;
};

}  // namespace dss
