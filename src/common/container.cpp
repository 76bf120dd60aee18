#include "digital_sun_sensor/common/container.h"

#include <algorithm>
#include <cstring>

#include "digital_sun_sensor/common/file_io.h"

namespace dss {
namespace {

constexpr std::size_t kMagicBytes = 8;
constexpr std::size_t kHeaderBytes = kMagicBytes + 4 + 4;
constexpr std::size_t kChecksumBytes = 8;

template <typename T>
void put(std::string& out, T value) {
  out.append(reinterpret_cast<const char*>(&value), sizeof(T));
}

template <typename T>
T take(const std::string& in, std::size_t offset) {
  T value;
  std::memcpy(&value, in.data() + offset, sizeof(T));
  return value;
}

}  // namespace

std::string packContainer(const char (&magic)[9], std::uint32_t version, const std::vector<std::string>& sections) {
  std::string out(magic, kMagicBytes);
  put<std::uint32_t>(out, version);
  put<std::uint32_t>(out, static_cast<std::uint32_t>(sections.size()));
  for (const auto& s : sections) put<std::uint64_t>(out, s.size());
  for (const auto& s : sections) out += s;
  put<std::uint64_t>(out, fnv1a64(out.data(), out.size()));
  return out;
}

Container unpackContainer(const std::string& bytes, const char (&magic)[9], const std::string& kind,
                          const std::string& origin, std::uint32_t legacy_sections) {
  if (bytes.size() < kHeaderBytes + kChecksumBytes || std::memcmp(bytes.data(), magic, kMagicBytes) != 0)
    throw ContainerError(origin + ": not a digital_sun_sensor " + kind +
                         " (bad magic or too short: " + std::to_string(bytes.size()) + " bytes)");
  Container c;
  c.version = take<std::uint32_t>(bytes, kMagicBytes);
  std::uint64_t count = take<std::uint32_t>(bytes, kMagicBytes + 4);
  if (count == 0) count = legacy_sections;
  const std::uint64_t table_end = kHeaderBytes + 8 * count;
  if (count > bytes.size() || table_end + kChecksumBytes > bytes.size())
    throw ContainerError(origin + ": truncated section table (" + std::to_string(bytes.size()) + " bytes)");
  std::uint64_t expected_size = table_end + kChecksumBytes;
  // A length beyond the file counts as one byte more than the file: the sum
  // stays far from overflow and still disagrees with the size.
  for (std::uint64_t i = 0; i < count; ++i)
    expected_size += std::min<std::uint64_t>(take<std::uint64_t>(bytes, kHeaderBytes + 8 * i), bytes.size() + 1);
  if (expected_size != bytes.size())
    throw ContainerError(origin + ": truncated or padded: " + std::to_string(bytes.size()) + " bytes, header says " +
                         std::to_string(expected_size));
  if (fnv1a64(bytes.data(), bytes.size() - kChecksumBytes) != take<std::uint64_t>(bytes, bytes.size() - kChecksumBytes))
    throw ContainerError(origin + ": checksum mismatch (the file is corrupt)");
  std::size_t at = table_end;
  for (std::uint64_t i = 0; i < count; ++i) {
    const auto n = take<std::uint64_t>(bytes, kHeaderBytes + 8 * i);
    c.sections.push_back(bytes.substr(at, n));
    at += n;
  }
  return c;
}

}  // namespace dss
