// Minimal JSON output helpers for the one-line reports (dss eval, dss report).
#pragma once

#include <cmath>
#include <cstdio>
#include <sstream>
#include <string>

namespace dss::json {

// A JSON number, or null for NaN / infinity.
inline std::string number(double v, int precision = 6) {
  if (!std::isfinite(v)) return "null";
  std::ostringstream os;
  os.precision(precision);
  os << v;
  return os.str();
}

// A JSON string literal (quotes, backslashes and control characters escaped).
inline std::string quoted(const std::string& s) {
  std::string out = "\"";
  for (const char c : s) {
    if (c == '"' || c == '\\') {
      out += '\\';
      out += c;
    } else if (static_cast<unsigned char>(c) < 0x20) {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\u%04x", c);
      out += buf;
    } else {
      out += c;
    }
  }
  return out + "\"";
}

}  // namespace dss::json
