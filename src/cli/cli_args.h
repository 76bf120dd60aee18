// Tiny command-line parser for dss subcommands: --flag value, --flag=value,
// repeatable options and boolean switches, with help text.
#pragma once

#include <map>
#include <stdexcept>
#include <string>
#include <vector>

namespace dss::cli {

class UsageError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct OptionSpec {
  std::string name;        // without dashes
  std::string value_name;  // empty: boolean switch
  std::string help;
  std::string default_value;
  bool required = false;
  bool repeatable = false;
};

// A number as an option's default text ("4", "0.001"): the shortest stream form.
std::string defaultText(double value);

class Args {
 public:
  Args(std::string command, std::string summary, std::vector<OptionSpec> specs);

  // Parses argv[first..]; throws UsageError naming the bad flag. Returns false
  // when --help was asked for (help already printed).
  bool parse(int argc, char** argv, int first);

  std::string help() const;
  bool has(const std::string& name) const;
  std::string get(const std::string& name) const;  // value or default
  std::vector<std::string> all(const std::string& name) const;
  long long getInt(const std::string& name) const;
  double getDouble(const std::string& name) const;

 private:
  const OptionSpec& spec(const std::string& name) const;

  std::string command_, summary_;
  std::vector<OptionSpec> specs_;
  std::map<std::string, std::vector<std::string>> values_;
};

}  // namespace dss::cli
