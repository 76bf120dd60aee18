// The package's one binary container, for model files and training
// checkpoints: an 8-byte magic naming the kind of file, a u32 format version,
// a u32 section count, a u64 length per section, the sections, and a u64
// FNV-1a checksum of everything before it (little-endian). Readers check the
// magic, the lengths against the file size and the checksum before they look
// at any section.
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace dss {

class ContainerError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

std::string packContainer(const char (&magic)[9], std::uint32_t version, const std::vector<std::string>& sections);

struct Container {
  std::uint32_t version = 0;
  std::vector<std::string> sections;
};

// Throws ContainerError "<origin>: what" for another magic ("not a <kind>"),
// a truncated or padded file or a checksum mismatch. A section count of 0
// stands for `legacy_sections` sections: model files of version 1 held their
// two lengths there with the count field reserved as 0.
Container unpackContainer(const std::string& bytes, const char (&magic)[9], const std::string& kind,
                          const std::string& origin, std::uint32_t legacy_sections = 0);

}  // namespace dss
