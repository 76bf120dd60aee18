// The active sites of a batch of sparse images at one resolution level:
// (batch index, row, column) triples with a hash index from coordinate to row.
// Rows of a feature matrix correspond to sites in this order. Torch-free.
#pragma once

#include <cstdint>
#include <stdexcept>
#include <vector>

namespace dss::sparse {

struct Site {
  std::int32_t batch = 0;
  std::int32_t y = 0;  // row
  std::int32_t x = 0;  // column
};

class SiteSet {
 public:
  // Throws std::invalid_argument on a site outside [0, batch_size) x [0, height)
  // x [0, width) or on a duplicate coordinate (a feature row each, always).
  SiteSet(int batch_size, int height, int width, std::vector<Site> sites);

  int size() const { return static_cast<int>(sites_.size()); }
  int batchSize() const { return batch_size_; }
  int height() const { return height_; }
  int width() const { return width_; }
  const std::vector<Site>& sites() const { return sites_; }
  const Site& site(int row) const { return sites_[static_cast<std::size_t>(row)]; }

  // Row of a site, or -1 when it is not active (or outside the extent).
  int find(int batch, int y, int x) const;

  // Active sites per batch image.
  std::vector<int> countsPerImage() const;

  // One 64-bit key per coordinate (21 bits per axis); keys sort as (batch, y, x).
  static std::uint64_t packKey(const Site& site);
  static Site unpackKey(std::uint64_t key);

 private:
  int batch_size_, height_, width_;
  std::vector<Site> sites_;
  // Open addressing with linear probing; capacity a power of two >= 2 size.
  std::vector<std::uint64_t> slot_keys_;
  std::vector<std::int32_t> slot_rows_;
  std::uint64_t slot_mask_ = 0;
};

}  // namespace dss::sparse
