// A smooth correction of an SSCNN's decoded angles. A trained network can keep
// a bias that varies slowly over the field of view (wide fields: more
// curvature than the head's degree-3 polynomial of the position follows),
// which no single image shows but many held-out images do. It is fitted after
// training by linear least squares on labelled held-out images
// (train/bias_calibration), recorded in the model file's metadata and
// subtracted in Model::decode. Torch-free.
#pragma once

#include <array>
#include <cstddef>
#include <vector>

namespace dss {

// Sum over i + j <= degree of c_ij P_i(a) P_j(b): Legendre polynomials of the
// normalized estimated angles (angle / the model's angle scale, clamped to
// [-1, 1]). Legendre rather than monomials: the degrees a wide field needs
// (10 and more) leave monomials too ill-conditioned for least squares.
struct AngleCorrection {
  static constexpr int kNone = -1;
  static constexpr int kMaxDegree = 24;

  int degree = kNone;
  // Per axis, termCount(degree) coefficients in normalized angle units, in
  // the order of terms().
  std::vector<double> alpha, beta;

  bool active() const { return degree != kNone; }
  static std::size_t termCount(int degree);
  // The basis at (a, b), by total degree, then by the power of b.
  static std::vector<double> terms(int degree, double a, double b);
  // The bias of normalized angles (a, b) estimated by the network: subtract it.
  std::array<double, 2> bias(double a, double b) const;
  // Throws std::invalid_argument naming the degree or coefficients at fault.
  void validate() const;
};

}  // namespace dss
