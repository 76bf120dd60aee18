// Runs of marked pixels along an image row: the renderer lights a mask's
// runs, the pattern solve reads the template along its pixels' runs.
#pragma once

#include <cstddef>
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

// Whether pred(row, col) holds for a marked pixel on the mask's edge (one
// of its eight neighbours unmarked; off the mask counts as marked), the
// mask being `rows` rows of `cols` bytes, `stride` bytes apart. Only marked
// pixels are visited, and a pixel's neighbours only where pred holds (put
// the cheap test in pred): an erosion of the whole mask costs more.
template <typename Pred>
bool anyOnMaskEdge(const std::uint8_t* mask, int rows, int cols, std::size_t stride, Pred&& pred) {
  const auto unmarked_near = [&](int r, int c) {  // in row r, at columns c - 1 .. c + 1
    if (r < 0 || r >= rows) return false;
    const std::uint8_t* m = mask + static_cast<std::size_t>(r) * stride;
    return (c > 0 && !m[c - 1]) || !m[c] || (c + 1 < cols && !m[c + 1]);
  };
  for (int r = 0; r < rows; ++r) {
    bool found = false;
    forEachRun(mask + static_cast<std::size_t>(r) * stride, cols, [&](int begin, int end) {
      for (int c = begin; c < end && !found; ++c)
        found = pred(r, c) && ((c == begin && c > 0) || (c + 1 == end && end < cols) || unmarked_near(r - 1, c) ||
                               unmarked_near(r + 1, c));
    });
    if (found) return true;
  }
  return false;
}

}  // namespace dss
