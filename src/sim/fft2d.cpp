#include "digital_sun_sensor/sim/fft2d.h"

#include <fftw3.h>

#include <map>
#include <mutex>
#include <new>
#include <utility>

namespace dss {
namespace {

std::mutex& planMutex() {
  static std::mutex m;
  return m;
}

// One forward and one inverse plan per size, made on scratch buffers and run
// with fftwf_execute_dft on any buffer of the same size and alignment.
std::pair<fftwf_plan, fftwf_plan> plansFor(int n) {
  static std::map<int, std::pair<fftwf_plan, fftwf_plan>> plans;
  std::lock_guard<std::mutex> lock(planMutex());
  auto it = plans.find(n);
  if (it != plans.end()) return it->second;
  auto* scratch = fftwf_alloc_complex(static_cast<std::size_t>(n) * n);
  fftwf_plan fwd = fftwf_plan_dft_2d(n, n, scratch, scratch, FFTW_FORWARD, FFTW_ESTIMATE);
  fftwf_plan inv = fftwf_plan_dft_2d(n, n, scratch, scratch, FFTW_BACKWARD, FFTW_ESTIMATE);
  fftwf_free(scratch);
  return plans[n] = {fwd, inv};
}

}  // namespace

ComplexGrid::ComplexGrid(int n) : n_(n) {
  data_ = reinterpret_cast<std::complex<float>*>(fftwf_alloc_complex(static_cast<std::size_t>(n) * n));
  if (!data_) throw std::bad_alloc();
}

ComplexGrid::~ComplexGrid() { fftwf_free(data_); }

void ComplexGrid::fill(std::complex<float> v) {
  for (std::size_t i = 0, e = static_cast<std::size_t>(n_) * n_; i < e; ++i) data_[i] = v;
}

void ComplexGrid::forward() {
  auto* p = reinterpret_cast<fftwf_complex*>(data_);
  fftwf_execute_dft(plansFor(n_).first, p, p);
}

void ComplexGrid::inverse() {
  auto* p = reinterpret_cast<fftwf_complex*>(data_);
  fftwf_execute_dft(plansFor(n_).second, p, p);
}

}  // namespace dss
