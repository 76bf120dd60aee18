// Minimal thread-safe wrapper over FFTW (single precision) for square 2-D
// complex transforms. Plans are created once per size under a global lock;
// execution on caller-owned aligned buffers is thread-safe.
#pragma once

#include <complex>
#include <cstddef>
#include <memory>

namespace dss {

class ComplexGrid {
 public:
  explicit ComplexGrid(int n);
  ~ComplexGrid();
  ComplexGrid(const ComplexGrid&) = delete;
  ComplexGrid& operator=(const ComplexGrid&) = delete;

  int size() const { return n_; }
  std::complex<float>* data() { return data_; }
  const std::complex<float>* data() const { return data_; }
  std::complex<float>& at(int row, int col) { return data_[static_cast<std::size_t>(row) * n_ + col]; }
  void fill(std::complex<float> v);

  // Unnormalized transforms in place: inverse(forward(x)) = n^2 x.
  void forward();
  void inverse();

 private:
  int n_;
  std::complex<float>* data_;
};

// Frequency (cycles per unit) of FFT bin k for n samples at spacing `step`.
inline double fftFrequency(int k, int n, double step) { return (k < n / 2 ? k : k - n) / (n * step); }

}  // namespace dss
