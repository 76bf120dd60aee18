// Marks a function whose hot loops run over arrays: on x86-64 Linux with
// GCC it is compiled twice, for AVX2 and for the build's baseline (SSE2),
// and the one to run is chosen when the library loads (target_clones, an
// ifunc). Both give the same results to the bit: the compiler vectorises a
// loop only where each element's operations keep their order (it does not
// reorder floating-point sums without -ffast-math), and AVX2 alone fuses
// no multiply-add (FMA is not enabled). A marked function is no longer
// inlined, nor are lambdas it passes on: where that cost more than the
// wider vectors saved (the pattern solve's pixel lists, the detector), it
// is not marked.
#pragma once

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && defined(__linux__)
#define DSS_VECTOR_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define DSS_VECTOR_CLONES
#endif
