// Runs of marked pixels along an image row: the renderer lights a mask's
// runs, the pattern solve reads the template along its pixels' runs.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstring>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif
#include <utility>
#include <vector>

namespace dss {

namespace row_runs_detail {

#if defined(__SSE2__)
// The first c' in [c, cols) whose byte is non-zero (`marked`) or zero (not
// `marked`), else cols: sixteen bytes per compare, the byte itself from the
// compare's bit mask.
inline int findByte(const std::uint8_t* row, int c, int cols, bool marked) {
  const __m128i zero = _mm_setzero_si128();
  for (; c + 16 <= cols; c += 16) {
    const __m128i bytes = _mm_loadu_si128(reinterpret_cast<const __m128i*>(row + c));
    const unsigned is_zero = static_cast<unsigned>(_mm_movemask_epi8(_mm_cmpeq_epi8(bytes, zero)));
    const unsigned hit = marked ? ~is_zero & 0xFFFFu : is_zero;
    if (hit) return c + __builtin_ctz(hit);
  }
  for (; c < cols; ++c)
    if ((row[c] != 0) == marked) return c;
  return cols;
}
#else
constexpr std::uint64_t kOnes = 0x0101010101010101ull, kHighs = 0x8080808080808080ull;

inline std::uint64_t eightBytes(const std::uint8_t* p) {
  std::uint64_t v;
  std::memcpy(&v, p, sizeof v);
  return v;
}

// Whether none of the eight bytes is zero (the classic zero-byte test).
inline bool noZeroByte(std::uint64_t v) { return ((v - kOnes) & ~v & kHighs) == 0; }
#endif

}  // namespace row_runs_detail

// Calls run(begin, end) for each run [begin, end) of non-zero bytes in
// row[0, cols), left to right. Masks are mostly long stretches of one
// kind: those are crossed sixteen bytes at a time (SSE2), else eight.
template <typename Run>
void forEachRun(const std::uint8_t* row, int cols, Run&& run) {
  using namespace row_runs_detail;
#if defined(__SSE2__)
  for (int c = findByte(row, 0, cols, true); c < cols; c = findByte(row, c, cols, true)) {
    const int begin = c;
    c = findByte(row, c, cols, false);
    run(begin, c);
  }
#else
  for (int c = 0; c < cols;) {
    while (c + 8 <= cols && eightBytes(row + c) == 0) c += 8;
    while (c < cols && !row[c]) ++c;
    if (c == cols) return;
    const int begin = c;
    while (c + 8 <= cols && noZeroByte(eightBytes(row + c))) c += 8;
    while (c < cols && row[c]) ++c;
    run(begin, c);
  }
#endif
}

// Calls edge(row, begin, end) for each run [begin, end) of the mask's edge
// pixels (marked, with one of their eight neighbours unmarked; off the mask
// counts as marked: an erosion by a 3 x 3 square with a marked border), row
// by row, left to right; the mask being `rows` rows of `cols` bytes,
// `stride` bytes apart. From the rows' runs: a pixel is inside where its
// row's runs and those of the rows above and below, each shrunk by a pixel
// at both ends, all hold it.
template <typename Edge>
void forEachEdgeRun(const std::uint8_t* mask, int rows, int cols, std::size_t stride, Edge&& edge) {
  using Runs = std::vector<std::pair<int, int>>;
  // Row r's runs into `runs`, and each shrunk by a pixel at both ends into `inner`.
  const auto read = [&](int r, Runs& runs, Runs& inner) {
    runs.clear(), inner.clear();
    if (r < 0 || r >= rows)
      runs.emplace_back(0, cols);  // off the mask: marked
    else
      forEachRun(mask + static_cast<std::size_t>(r) * stride, cols, [&](int b, int e) { runs.emplace_back(b, e); });
    for (const auto& [b, e] : runs) {
      const int from = b == 0 ? 0 : b + 1, to = e == cols ? cols : e - 1;
      if (from < to) inner.emplace_back(from, to);
    }
  };
  // x = x and y (both sorted, disjoint runs).
  Runs scratch;
  const auto intersect = [&scratch](Runs& x, const Runs& y) {
    scratch.clear();
    for (std::size_t i = 0, j = 0; i < x.size() && j < y.size();) {
      const int from = std::max(x[i].first, y[j].first), to = std::min(x[i].second, y[j].second);
      if (from < to) scratch.emplace_back(from, to);
      if (x[i].second < y[j].second)
        ++i;
      else
        ++j;
    }
    x.swap(scratch);
  };
  // Rows r - 1, r, r + 1 (rolling), their shrunk runs, and row r's inside.
  Runs above, above_in, here, here_in, below, below_in, inside;
  read(-1, above, above_in);
  read(0, here, here_in);
  for (int r = 0; r < rows; ++r) {
    read(r + 1, below, below_in);
    inside = here_in;
    intersect(inside, above_in);
    intersect(inside, below_in);
    // Each run of the row less the inside runs (which lie within the row's runs).
    std::size_t k = 0;
    for (const auto& [b, e] : here) {
      int c = b;
      for (; k < inside.size() && inside[k].first < e; ++k) {
        if (c < inside[k].first) edge(r, c, inside[k].first);
        c = inside[k].second;
      }
      if (c < e) edge(r, c, e);
    }
    above.swap(here), above_in.swap(here_in);
    here.swap(below), here_in.swap(below_in);
  }
}

}  // namespace dss
