// A spot's centre as its point of symmetry: the c that minimises
// sum_p (I(p) - I(2c - p))^2 over a patch of the pixel grid, I read between
// pixels by Catmull-Rom interpolation (zero outside the patch). A spot whose
// light is point-symmetric about its centre (a round aperture's diffraction
// disk, the sun's disk, their projection through the cover glass) is fitted
// from the slopes of its flanks, which carry the position: the noise of this
// read-out goes as 1 / sum |grad I|^2, that of an intensity-weighted centroid
// as the spot's spread over its light: on wide_ma's spots it is 6-34 %
// smaller, on drawn mask A's broad spots cut at half their peak 20 % larger
// (docs/sscnn.md#symmetric-spot-read-out). A flat threshold (an on-chip
// rescale, v = max(0, d - level)) leaves the spot symmetric.
#pragma once

#include <Eigen/Core>
#include <optional>
#include <vector>

namespace dss {

struct SymmetryPatch {
  int cols = 0, rows = 0;
  std::vector<double> values;  // row-major, cols * rows; zero where dark
  double at(int col, int row) const {
    return col < 0 || row < 0 || col >= cols || row >= rows
               ? 0.0
               : values[static_cast<std::size_t>(row) * static_cast<std::size_t>(cols) + static_cast<std::size_t>(col)];
  }
};

struct SymmetryOptions {
  int max_iterations = 6;
  double converged_px = 1e-4;  // a Gauss-Newton step shorter than this ends the fit
  double max_move_px = 2.0;    // from the start: farther is no fit
};

// Gauss-Newton from `start` (column, row in the patch). nullopt where the
// normal matrix is singular, the fit leaves max_move_px or does not converge.
std::optional<Eigen::Vector2d> symmetryCentre(const SymmetryPatch& patch, const Eigen::Vector2d& start,
                                              const SymmetryOptions& options = {});

}  // namespace dss
