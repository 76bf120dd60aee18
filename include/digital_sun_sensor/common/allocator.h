// Heap policy for the numeric work. glibc serves blocks above a dynamic
// threshold (128 kB to 32 MB) by mmap and returns them, and the top of the
// heap above 128 kB, to the system when freed. A training step allocates and
// frees feature, gather and im2col buffers of up to ~100 MB each, so every
// step faulted fresh zeroed pages in again: on wide_ma (3100 sites per image,
// batch 64) more kernel than compute time. Keeping freed memory in the process
// for reuse made `dss bench train` 2.3 times faster (65 -> 149 images/s); the
// price is that the process keeps its peak heap (about 3 GB training wide_ma).
#pragma once

namespace dss {

// Serves every allocation from the heap and never trims it (mallopt
// M_MMAP_THRESHOLD, then M_TRIM_THRESHOLD). Call once, before the numeric
// work; returns false when the C library refused either (if the second, the
// first stays set).
bool retainFreedMemory();

}  // namespace dss
