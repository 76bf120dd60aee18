// Runs of marked pixels along an image row: the renderer lights a mask's
// runs, the pattern solve reads the template along its pixels' runs.
#pragma once

#include <cstdint>
#include <cstring>

namespace dss {

namespace row_runs_detail {

constexpr std::uint64_t kOnes = 0x0101010101010101ull, kHighs = 0x8080808080808080ull;

inline std::uint64_t eightBytes(const std::uint8_t* p) {
  std::uint64_t v;
  std::memcpy(&v, p, sizeof v);
  return v;
}

// Whether none of the eight bytes is zero (the classic zero-byte test).
inline bool noZeroByte(std::uint64_t v) { return ((v - kOnes) & ~v & kHighs) == 0; }

}  // namespace row_runs_detail

// Calls run(begin, end) for each run [begin, end) of non-zero bytes in
// row[0, cols), left to right. Masks are mostly long stretches of one
// kind: those are crossed eight bytes at a time.
template <typename Run>
void forEachRun(const std::uint8_t* row, int cols, Run&& run) {
  using namespace row_runs_detail;
  for (int c = 0; c < cols;) {
    while (c + 8 <= cols && eightBytes(row + c) == 0) c += 8;
    while (c < cols && !row[c]) ++c;
    if (c == cols) return;
    const int begin = c;
    while (c + 8 <= cols && noZeroByte(eightBytes(row + c))) c += 8;
    while (c < cols && row[c]) ++c;
    run(begin, c);
  }
}

}  // namespace dss
