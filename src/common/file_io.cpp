#include "digital_sun_sensor/common/file_io.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include "digital_sun_sensor/common/limits.h"

namespace dss {

void writeFileAtomic(const std::string& path, const std::string& bytes) {
  const std::string tmp = path + ".tmp." + std::to_string(::getpid());
  auto fail = [&](const std::string& what) {
    const std::string reason = std::strerror(errno);
    ::unlink(tmp.c_str());
    throw std::runtime_error("cannot write '" + path + "': " + what + ": " + reason);
  };
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) fail("open " + tmp);
  std::size_t written = 0;
  while (written < bytes.size()) {
    const ssize_t n = ::write(fd, bytes.data() + written, bytes.size() - written);
    if (n < 0) {
      if (errno == EINTR) continue;
      ::close(fd);
      fail("write");
    }
    written += static_cast<std::size_t>(n);
  }
  if (::fsync(fd) != 0) {
    ::close(fd);
    fail("fsync");
  }
  if (::close(fd) != 0) fail("close");
  if (std::rename(tmp.c_str(), path.c_str()) != 0) fail("rename");
  // The rename itself reaches the disk with the directory's entry.
  const std::string dir = path.find('/') == std::string::npos ? "." : path.substr(0, path.rfind('/') + 1);
  const int dir_fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dir_fd >= 0) {
    ::fsync(dir_fd);
    ::close(dir_fd);
  }
}

void replaceDirectory(const std::string& staged, const std::string& path) {
  namespace fs = std::filesystem;
  const std::string old = path + ".old";
  std::error_code error;
  fs::remove_all(old, error);
  if (fs::exists(path) && std::rename(path.c_str(), old.c_str()) != 0)
    throw std::runtime_error("cannot move '" + path + "' aside: " + std::strerror(errno));
  if (std::rename(staged.c_str(), path.c_str()) != 0)
    throw std::runtime_error("cannot move '" + staged + "' to '" + path + "': " + std::strerror(errno));
  fs::remove_all(old, error);
}

std::string readFile(const std::string& path, std::uint64_t max_bytes) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error("cannot open '" + path + "': " + std::strerror(errno));
  struct stat info {};
  if (::stat(path.c_str(), &info) == 0 && S_ISREG(info.st_mode) && static_cast<std::uint64_t>(info.st_size) > max_bytes)
    throw std::runtime_error("'" + path + "' is " + limits::describeBytes(static_cast<std::uint64_t>(info.st_size)) +
                             ", over the limit of " + limits::describeBytes(max_bytes));
  // Read in blocks up to the limit: a pipe or device has no size to check.
  std::string bytes;
  char block[1 << 16];
  while (in) {
    in.read(block, sizeof block);
    bytes.append(block, static_cast<std::size_t>(in.gcount()));
    if (bytes.size() > max_bytes)
      throw std::runtime_error("'" + path + "' is over the limit of " + limits::describeBytes(max_bytes));
  }
  if (in.bad()) throw std::runtime_error("cannot read '" + path + "'");
  return bytes;
}

std::uint64_t fnv1a64(const char* data, std::size_t n) {
  std::uint64_t h = 0xcbf29ce484222325ULL;
  for (std::size_t i = 0; i < n; ++i) {
    h ^= static_cast<unsigned char>(data[i]);
    h *= 0x100000001b3ULL;
  }
  return h;
}

}  // namespace dss
