// Whole-file reads and atomic writes (readers see either the old or the
// complete new content: temp file in the same directory, fsync, rename).
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>

namespace dss {

// Throws std::runtime_error naming the path and the OS error.
void writeFileAtomic(const std::string& path, const std::string& bytes);

// Whole file; throws std::runtime_error naming the path when unreadable.
std::string readFile(const std::string& path);

// 64-bit FNV-1a: the checksum of model and checkpoint files.
std::uint64_t fnv1a64(const char* data, std::size_t n);

}  // namespace dss
