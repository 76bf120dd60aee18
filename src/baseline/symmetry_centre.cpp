#include "digital_sun_sensor/baseline/symmetry_centre.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>

#include "digital_sun_sensor/common/cubic_weights.h"

namespace dss {

std::optional<Eigen::Vector2d> symmetryCentre(const SymmetryPatch& patch, const Eigen::Vector2d& start,
                                              const SymmetryOptions& options) {
  if (patch.cols < 1 || patch.rows < 1) return std::nullopt;
  const auto cols = static_cast<std::size_t>(patch.cols);
  // The mirror image R(p) = I(2c - p) and its gradient in c: at a given c
  // every pixel's mirror point has the same fraction, so the cubic weights
  // are computed once per iteration and R is a separable 4 x 4 filter of
  // the patch read backwards. h0 / h1: rows filtered along x with the
  // weights / their derivatives, for every row the vertical taps reach.
  std::vector<double> h0(static_cast<std::size_t>(patch.rows) * cols), h1(h0.size());
  Eigen::Vector2d c = start;
  for (int iteration = 0; iteration < options.max_iterations; ++iteration) {
    const double x2 = 2.0 * c.x(), y2 = 2.0 * c.y();
    const int fx = static_cast<int>(std::floor(x2)), fy = static_cast<int>(std::floor(y2));
    double wx[4], dx[4], wy[4], dy[4];
    cubicWeights(x2 - fx, wx, dx);
    cubicWeights(y2 - fy, wy, dy);
    // h*(row s, col i) = sum_a w_a I(s, fx - i + a - 1); the four taps lie
    // inside the patch for i in [inner_lo, inner_hi].
    const int inner_lo = std::max(0, fx - patch.cols + 3), inner_hi = std::min(patch.cols - 1, fx - 1);
    for (int s = 0; s < patch.rows; ++s) {
      const double* row = &patch.values[static_cast<std::size_t>(s) * cols];
      double* out0 = &h0[static_cast<std::size_t>(s) * cols];
      double* out1 = &h1[static_cast<std::size_t>(s) * cols];
      for (int i = 0; i < patch.cols; ++i) {
        double v0 = 0.0, v1 = 0.0;
        if (i >= inner_lo && i <= inner_hi) {
          const double* tap = row + (fx - i - 1);
          for (int a = 0; a < 4; ++a) {
            v0 += wx[a] * tap[a];
            v1 += dx[a] * tap[a];
          }
        } else {
          for (int a = 0; a < 4; ++a) {
            const double value = patch.at(fx - i + a - 1, s);
            v0 += wx[a] * value;
            v1 += dx[a] * value;
          }
        }
        out0[i] = v0;
        out1[i] = v1;
      }
    }
    Eigen::Matrix2d normal = Eigen::Matrix2d::Zero();
    Eigen::Vector2d gradient = Eigen::Vector2d::Zero();
    for (int j = 0; j < patch.rows; ++j)
      for (int i = 0; i < patch.cols; ++i) {
        double r = 0.0, rx = 0.0, ry = 0.0;
        for (int b = 0; b < 4; ++b) {
          const int s = fy - j + b - 1;
          if (s < 0 || s >= patch.rows) continue;
          const std::size_t k = static_cast<std::size_t>(s) * cols + static_cast<std::size_t>(i);
          r += wy[b] * h0[k];
          rx += wy[b] * h1[k];
          ry += dy[b] * h0[k];
        }
        const double residual = patch.at(i, j) - r;
        if (residual == 0.0 && rx == 0.0 && ry == 0.0) continue;
        const Eigen::Vector2d jac(-2.0 * rx, -2.0 * ry);  // d residual / d c
        normal.noalias() += jac * jac.transpose();
        gradient.noalias() += jac * residual;
      }
    if (!(normal.determinant() > 0.0)) return std::nullopt;
    const Eigen::Vector2d step = -normal.ldlt().solve(gradient);
    if (!step.allFinite()) return std::nullopt;
    c += step;
    if ((c - start).norm() > options.max_move_px) return std::nullopt;
    if (step.norm() < options.converged_px) return c;
  }
  return std::nullopt;
}

}  // namespace dss
