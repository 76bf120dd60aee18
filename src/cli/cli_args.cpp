#include "cli_args.h"

#include <iostream>
#include <sstream>

namespace dss::cli {

Args::Args(std::string command, std::string summary, std::vector<OptionSpec> specs)
    : command_(std::move(command)), summary_(std::move(summary)), specs_(std::move(specs)) {}

const OptionSpec& Args::spec(const std::string& name) const {
  for (const auto& s : specs_) {
    if (s.name == name) return s;
  }
  throw UsageError(command_ + ": unknown option --" + name + " (see " + command_ + " --help)");
}

bool Args::parse(int argc, char** argv, int first) {
  for (int i = first; i < argc; ++i) {
    std::string a = argv[i];
    if (a == "--help" || a == "-h") {
      std::cout << help();
      return false;
    }
    if (a.rfind("--", 0) != 0) throw UsageError(command_ + ": unexpected argument '" + a + "'");
    std::string name = a.substr(2), value;
    bool inline_value = false;
    if (auto eq = name.find('='); eq != std::string::npos) {
      value = name.substr(eq + 1);
      name = name.substr(0, eq);
      inline_value = true;
    }
    const OptionSpec& s = spec(name);
    if (s.value_name.empty()) {
      if (inline_value) throw UsageError(command_ + ": --" + name + " takes no value");
      value = "1";
    } else if (!inline_value) {
      if (i + 1 >= argc) throw UsageError(command_ + ": --" + name + " needs a value " + s.value_name);
      value = argv[++i];
    }
    auto& v = values_[name];
    if (!v.empty() && !s.repeatable) throw UsageError(command_ + ": --" + name + " given twice");
    v.push_back(value);
  }
  for (const auto& s : specs_) {
    if (s.required && !has(s.name)) throw UsageError(command_ + ": missing required --" + s.name + " " + s.value_name);
  }
  return true;
}

std::string defaultText(double value) {
  std::ostringstream o;
  o << value;
  return o.str();
}

std::string Args::help() const {
  std::ostringstream o;
  o << "usage: " << command_;
  for (const auto& s : specs_) {
    std::string flag = "--" + s.name + (s.value_name.empty() ? "" : " " + s.value_name);
    o << ' ' << (s.required ? flag : "[" + flag + "]");
  }
  o << "\n\n" << summary_ << "\n\noptions:\n";
  for (const auto& s : specs_) {
    std::string flag = "--" + s.name + (s.value_name.empty() ? "" : " " + s.value_name);
    o << "  " << flag;
    for (std::size_t pad = flag.size(); pad < 26; ++pad) o << ' ';
    o << ' ' << s.help;
    if (!s.default_value.empty()) o << " (default: " << s.default_value << ")";
    if (s.repeatable) o << " [repeatable]";
    o << '\n';
  }
  return o.str();
}

bool Args::has(const std::string& name) const { return values_.count(name) > 0; }

std::string Args::get(const std::string& name) const {
  auto it = values_.find(name);
  return it == values_.end() ? spec(name).default_value : it->second.front();
}

std::vector<std::string> Args::all(const std::string& name) const {
  auto it = values_.find(name);
  return it == values_.end() ? std::vector<std::string>{} : it->second;
}

long long Args::getInt(const std::string& name) const {
  const std::string v = get(name);
  try {
    std::size_t used = 0;
    long long x = std::stoll(v, &used);
    if (used == v.size()) return x;
  } catch (const std::exception&) {
  }
  throw UsageError(command_ + ": --" + name + " expects an integer, got '" + v + "'");
}

double Args::getDouble(const std::string& name) const {
  const std::string v = get(name);
  try {
    std::size_t used = 0;
    double x = std::stod(v, &used);
    if (used == v.size()) return x;
  } catch (const std::exception&) {
  }
  throw UsageError(command_ + ": --" + name + " expects a number, got '" + v + "'");
}

}  // namespace dss::cli
