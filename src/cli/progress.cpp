#include "progress.h"

#include <unistd.h>

#include <cstdio>

namespace dss::cli {

Progress::Progress(std::string label, std::uint64_t total)
    : label_(std::move(label)), total_(total), tty_(isatty(fileno(stderr)) != 0), start_(std::chrono::steady_clock::now()) {}

void Progress::update(std::uint64_t done) {
  const auto now = std::chrono::steady_clock::now();
  const double elapsed = std::chrono::duration<double>(now - start_).count();
  const double fraction = total_ ? static_cast<double>(done) / total_ : 1.0;
  const double rate = elapsed > 0 ? done / elapsed : 0.0;
  const double eta = rate > 0 ? (total_ - done) / rate : 0.0;
  const int decile = static_cast<int>(fraction * 10);
  if (tty_) {
    if (done < total_ && now - last_draw_ < std::chrono::milliseconds(100)) return;
    last_draw_ = now;
    constexpr int kWidth = 30;
    const int fill = static_cast<int>(fraction * kWidth);
    std::fprintf(stderr, "\r%s %llu/%llu [%.*s%*s] %.1f/s ETA %d:%02d", label_.c_str(),
                 static_cast<unsigned long long>(done), static_cast<unsigned long long>(total_), fill,
                 "==============================", kWidth - fill, "", rate, static_cast<int>(eta) / 60,
                 static_cast<int>(eta) % 60);
  } else if (decile != last_decile_) {
    last_decile_ = decile;
    std::fprintf(stderr, "%s %llu/%llu (%d%%) %.1f/s ETA %ds\n", label_.c_str(), static_cast<unsigned long long>(done),
                 static_cast<unsigned long long>(total_), static_cast<int>(fraction * 100), rate, static_cast<int>(eta));
  }
  std::fflush(stderr);
}

void Progress::finish() {
  if (tty_) std::fprintf(stderr, "\n");
}

}  // namespace dss::cli
