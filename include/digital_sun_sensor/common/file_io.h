// Whole-file reads and atomic writes (readers see either the old or the
// complete new content: temp file in the same directory, fsync, rename).
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>

namespace dss {

// Throws std::runtime_error naming the path and the OS error.
void writeFileAtomic(const std::string& path, const std::string& bytes);

// Puts the directory `staged` (complete) in place of `path`: the old `path`
// is moved aside and removed after the new one is in, so `path` is never a
// mix of the two. Throws std::runtime_error naming the paths.
void replaceDirectory(const std::string& staged, const std::string& path);

// Whole file; throws std::runtime_error naming the path when unreadable or
// larger than `max_bytes` (checked before anything is read).
std::string readFile(const std::string& path, std::uint64_t max_bytes);

// 64-bit FNV-1a: the checksum of model and checkpoint files.
std::uint64_t fnv1a64(const char* data, std::size_t n);

}  // namespace dss
