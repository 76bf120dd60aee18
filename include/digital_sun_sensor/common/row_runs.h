// Runs of marked pixels along an image row: the renderer lights a mask's
// runs, the pattern solve reads the template along its pixels' runs.
#pragma once

#include <cstdint>

namespace dss {

// Calls run(begin, end) for each run [begin, end) of non-zero bytes in
// row[0, cols), left to right.
template <typename Run>
void forEachRun(const std::uint8_t* row, int cols, Run&& run) {
  for (int c = 0; c < cols;) {
    if (!row[c]) {
      ++c;
      continue;
    }
    const int begin = c;
    while (c < cols && row[c]) ++c;
    run(begin, c);
  }
}

}  // namespace dss
