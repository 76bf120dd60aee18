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
#include <utility>
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

// How the angle correction changes with the mask height (geometric head): a
// unit whose mask sits higher above its glass window (an air gap) or lower
// in it (a thinner window) shapes its spots otherwise (diffraction in air
// spreads a spot near 60 deg four times more per um than in glass), which
// moves where the network reads them by up to 0.06 um: 0.009 deg. `change`
// is fitted on images of the design with its mask moved by
// `height_change_um` (the model's geometry moved alike), relative to the
// design's correction.
struct HeightCorrection {
  double height_change_um = 0.0;
  AngleCorrection change;
  // Throws std::invalid_argument for a zero or non-finite height change or a bad correction.
  void validate() const;
};

// Where a quantity fitted at a few mask height changes (entries; the design
// itself is a change of 0 with no change of the quantity) is taken at
// `height_change_um`: linearly between the two entries of the same sign that
// bracket it (or the design and the nearest), along the last two beyond the
// farthest. Up to two (entry index, weight) pairs; an index of -1 is the
// design's no change; no entry on that side: none.
std::vector<std::pair<int, double>> heightInterpolation(const std::vector<double>& entry_changes_um,
                                                        double height_change_um);

// The correction for a geometry whose mask height differs from the design's
// by `height_change_um`: the design's, plus the changes of the entries of
// the same sign interpolated linearly in the height between the design (no
// change) and the entries, and extrapolated along the last two beyond the
// farthest (the change is not proportional to the height: a 10 um air gap
// moves the reading near the corners four fifths as far as a 20 um one).
class UnitAngleCorrection {
 public:
  UnitAngleCorrection(const AngleCorrection& design, const std::vector<HeightCorrection>& by_height,
                      double height_change_um);
  std::array<double, 2> bias(double a, double b) const;

 private:
  const AngleCorrection& design_;
  // Up to two entries and their weights (an entry of nullptr: the design's no change).
  std::array<const AngleCorrection*, 2> changes_{nullptr, nullptr};
  std::array<double, 2> weights_{0.0, 0.0};
};

}  // namespace dss
