#include "digital_sun_sensor/sparse/site_set.h"

#include <string>

namespace dss::sparse {
namespace {

constexpr std::uint64_t kEmpty = ~std::uint64_t{0};

std::uint64_t mix(std::uint64_t k) {  // splitmix64 finaliser: spreads neighbouring pixels
  k ^= k >> 31;
  k *= 0x7fb5d329728ea185ULL;
  k ^= k >> 27;
  k *= 0x81dadef4bc2dd44dULL;
  return k ^ (k >> 33);
}

}  // namespace

std::uint64_t SiteSet::packKey(const Site& s) {
  return (static_cast<std::uint64_t>(s.batch) << 42) | (static_cast<std::uint64_t>(s.y) << 21) |
         static_cast<std::uint64_t>(s.x);
}

Site SiteSet::unpackKey(std::uint64_t key) {
  return {static_cast<std::int32_t>(key >> 42), static_cast<std::int32_t>((key >> 21) & 0x1FFFFF),
          static_cast<std::int32_t>(key & 0x1FFFFF)};
}

SiteSet::SiteSet(int batch_size, int height, int width, std::vector<Site> sites)
    : batch_size_(batch_size), height_(height), width_(width), sites_(std::move(sites)) {
  if (batch_size < 0 || height <= 0 || width <= 0 || height >= (1 << 21) || width >= (1 << 21))
    throw std::invalid_argument("SiteSet: bad extent " + std::to_string(batch_size) + "x" + std::to_string(height) +
                                "x" + std::to_string(width));
  std::uint64_t capacity = 16;
  while (capacity < 2 * sites_.size()) capacity *= 2;
  slot_keys_.assign(capacity, kEmpty);
  slot_rows_.assign(capacity, -1);
  slot_mask_ = capacity - 1;
  for (std::size_t row = 0; row < sites_.size(); ++row) {
    const Site& s = sites_[row];
    if (s.batch < 0 || s.batch >= batch_size || s.y < 0 || s.y >= height || s.x < 0 || s.x >= width)
      throw std::invalid_argument("SiteSet: site (batch " + std::to_string(s.batch) + ", y " + std::to_string(s.y) +
                                  ", x " + std::to_string(s.x) + ") lies outside the " + std::to_string(batch_size) +
                                  "x" + std::to_string(height) + "x" + std::to_string(width) + " extent");
    const std::uint64_t k = packKey(s);
    std::uint64_t slot = mix(k) & slot_mask_;
    while (slot_keys_[slot] != kEmpty) {
      if (slot_keys_[slot] == k)
        throw std::invalid_argument("SiteSet: duplicate site (batch " + std::to_string(s.batch) + ", y " +
                                    std::to_string(s.y) + ", x " + std::to_string(s.x) + ")");
      slot = (slot + 1) & slot_mask_;
    }
    slot_keys_[slot] = k;
    slot_rows_[slot] = static_cast<std::int32_t>(row);
  }
}

int SiteSet::find(int batch, int y, int x) const {
  if (y < 0 || y >= height_ || x < 0 || x >= width_ || batch < 0 || batch >= batch_size_) return -1;
  const std::uint64_t k = packKey({batch, y, x});
  for (std::uint64_t slot = mix(k) & slot_mask_;; slot = (slot + 1) & slot_mask_) {
    if (slot_keys_[slot] == k) return slot_rows_[slot];
    if (slot_keys_[slot] == kEmpty) return -1;
  }
}

std::vector<int> SiteSet::countsPerImage() const {
  std::vector<int> counts(static_cast<std::size_t>(batch_size_), 0);
  for (const Site& s : sites_) ++counts[static_cast<std::size_t>(s.batch)];
  return counts;
}

}  // namespace dss::sparse
