// Thread budget of the two compute pools on a small machine. ATen (OpenMP)
// runs the element-wise ops; OpenBLAS (pthreads) runs the sparse convolution
// GEMMs. Letting both spawn one thread per core oversubscribes the cores, so
// one of them gets one thread (measured: dss bench infer/train --aten-threads
// --blas-threads; README). The first call also keeps freed memory in the
// process for reuse (common/allocator.h), which every front end that runs the
// network wants.
#pragma once

#include <string>

namespace dss::sparse {

void configureThreads(int aten_threads, int blas_threads);
std::string threadSummary();  // "aten=1 blas=2"

}  // namespace dss::sparse
