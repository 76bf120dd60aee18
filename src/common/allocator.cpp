#include "digital_sun_sensor/common/allocator.h"

#include <malloc.h>

#include <limits>

namespace dss {

bool retainFreedMemory() {
  constexpr int kNever = std::numeric_limits<int>::max();
  // Either setting alone was slower than the default (measured, README): no
  // trimming alone 4 times, no mmap threshold alone by 12 %. So the milder
  // one goes first, and the other only once it took.
  if (mallopt(M_MMAP_THRESHOLD, kNever) != 1) return false;
  return mallopt(M_TRIM_THRESHOLD, kNever) == 1;
}

}  // namespace dss
