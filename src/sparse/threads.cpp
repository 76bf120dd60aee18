#include "digital_sun_sensor/sparse/threads.h"

#include <ATen/Parallel.h>
#include <openblas-pthread/cblas.h>

#include <algorithm>
#include <stdexcept>

#include "digital_sun_sensor/common/allocator.h"

namespace dss::sparse {

void configureThreads(int aten_threads, int blas_threads) {
  if (aten_threads < 1 || blas_threads < 1)
    throw std::invalid_argument("thread counts must be at least 1 (aten " + std::to_string(aten_threads) + ", blas " +
                                std::to_string(blas_threads) + ")");
  at::set_num_threads(aten_threads);
  // Inter-op parallelism is unused (one graph at a time); ATen allows setting it once per process.
  static const bool interop_set = [] {
    at::set_num_interop_threads(1);
    return true;
  }();
  (void)interop_set;
  openblas_set_num_threads(blas_threads);
  static const bool heap_retained = retainFreedMemory();
  (void)heap_retained;
}

std::string threadSummary() {
  return "aten=" + std::to_string(at::get_num_threads()) + " blas=" + std::to_string(openblas_get_num_threads());
}

}  // namespace dss::sparse
