// Each fuzz target defines DSS_FUZZ_ENTRY: LLVMFuzzerTestOneInput in the
// libFuzzer build (-DDSS_FUZZ=ON), a named function in the regression test
// that replays the committed inputs (test/test_fuzz_regressions.cpp).
//
// The rule every target checks: an input is either accepted or refused with
// the reader's own error type; anything else (another exception, a crash, a
// sanitizer report, a hang) is a finding.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#ifndef DSS_FUZZ_ENTRY
#define DSS_FUZZ_ENTRY LLVMFuzzerTestOneInput
#endif

namespace dss {
namespace fuzz {

// Splits an input at NUL bytes: the parts a target feeds to different
// readers (a file and its --set overrides; container sections).
inline std::vector<std::string> splitAtNul(const std::uint8_t* data, std::size_t size, std::size_t max_parts) {
  std::vector<std::string> parts(1);
  for (std::size_t i = 0; i < size; ++i) {
    if (data[i] == 0 && parts.size() < max_parts)
      parts.emplace_back();
    else
      parts.back().push_back(static_cast<char>(data[i]));
  }
  return parts;
}

// Where the targets find the package's files (sensor configs, models).
inline std::string sourceDir() {
#ifdef DSS_SOURCE_DIR
  return DSS_SOURCE_DIR;
#else
  return ".";
#endif
}

}  // namespace fuzz
}  // namespace dss
