#include "digital_sun_sensor/common/allocator.h"

#include <malloc.h>

#include <limits>

namespace dss {

bool retainFreedMemory() {
  constexpr int kNever = std::numeric_limits<int>::max();
  // Both or nothing: a heap that is never trimmed but still maps large blocks
  // (or the reverse) was slower than the default (measured, README).
  if (mallopt(M_MMAP_THRESHOLD, kNever) != 1) return false;
  return mallopt(M_TRIM_THRESHOLD, kNever) == 1;
}

}  // namespace dss
