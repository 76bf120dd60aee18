// Progress bar on stderr: redrawn in place on a terminal, a line every 10%
// otherwise (logs, CI).
#pragma once

#include <chrono>
#include <cstdint>
#include <string>

namespace dss::cli {

class Progress {
 public:
  Progress(std::string label, std::uint64_t total);
  void update(std::uint64_t done);
  void finish();

 private:
  std::string label_;
  std::uint64_t total_;
  bool tty_;
  int last_decile_ = -1;
  std::chrono::steady_clock::time_point start_, last_draw_;
};

}  // namespace dss::cli
