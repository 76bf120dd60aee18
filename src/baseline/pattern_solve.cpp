#include "digital_sun_sensor/baseline/pattern_solve.h"

#include <Eigen/Dense>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <utility>

#include "digital_sun_sensor/common/row_runs.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/common/vector_clones.h"
#include "digital_sun_sensor/sim/geometry.h"

namespace dss {

// Lit pixels and the dark ones next to them, the image's total light and,
// per search level, its sums over the level's blocks.
struct PatternSolver::Pixels {
  struct Pixel {
    int col, row;
    double value;  // [DN]
  };
  std::vector<Pixel> lit, dark;
  // The same pixels as row runs in raster order (the fit on every pixel
  // reads the template along them): pixels (col + i, row), i < count, with
  // values[first + i] (> 0: lit).
  struct Run {
    int col, row, count;
    std::size_t first;
  };
  std::vector<Run> runs;
  int widest_run = 0;
  std::vector<double> values;
  double total = 0.0;
  std::vector<cv::Mat> block_sums;  // per level, CV_64F, ceil(rows / factor) x ceil(cols / factor)
  // Per level above the coarse one, row of blocks and phase p < 4: the
  // runs [begin, end) of whole groups of four blocks from a column = p
  // (mod 4) that hold light (merged; end may pass the row's), in raster
  // order and phase by phase; row r's at phase p are
  // lit_groups[lit_groups_first[4 r + p] .. lit_groups_first[4 r + p + 1]) (litDot).
  std::vector<std::vector<std::pair<int, int>>> lit_groups;
  std::vector<std::vector<int>> lit_groups_first;
};

// A block-averaged template above a level (what a lit pixel can lie on),
// with its integral image for the light it puts in the detector window.
struct PatternSolver::Level {
  int factor = 1;
  int cols = 0, rows = 0;
  double step_um = 1.0;
  double centre_u = 0.0, centre_v = 0.0;  // cell whose centre is the template's
  cv::Mat values;                         // CV_64F rows x cols
  cv::Mat integral;                       // CV_64F (rows + 1) x (cols + 1)
  cv::Mat mirrored;                       // values, each row right to left (the global search reads it so)

  // Sum over template cells [u0, u1) x [v0, v1), clipped to the template.
  double sum(int u0, int v0, int u1, int v1) const {
    u0 = std::clamp(u0, 0, cols), u1 = std::clamp(u1, 0, cols);
    v0 = std::clamp(v0, 0, rows), v1 = std::clamp(v1, 0, rows);
    if (u1 <= u0 || v1 <= v0) return 0.0;
    return integral.at<double>(v1, u1) - integral.at<double>(v0, u1) - integral.at<double>(v1, u0) +
           integral.at<double>(v0, u0);
  }
};

PatternSolver::PatternSolver(const SensorConfig& config, PatternSolveOptions options)
    : config_(config), options_(options), template_(std::make_shared<PatternTemplate>(config)) {
  drift_ = MaskGeometry::nominalOf(config);
  drift_.apertures_um = {Eigen::Vector2d::Zero()};
  drift_.aperture_diameters_um = {0.0};
  drift_.air_above_exit_um = 0.5 * config.mask.thickness_mm * 1000.0;
  drift_.height_um = config.mask.height_mm * 1000.0 + drift_.air_above_exit_um;
  top_ = config.maxCode();
  const double level = config.threshold.enabled ? config.threshold.level_fraction : 0.0;
  if (config.threshold.enabled && config.threshold.rescale) {
    offset_ = level / (1.0 - level) * top_;  // value = (code - level top) / (1 - level)
    floor_ = 0.0;
  } else {
    offset_ = -config.noise.black_level_dn;
    floor_ = config.threshold.enabled ? level * top_ : -std::numeric_limits<double>::infinity();
  }
  if (options_.middle_factor < 1 || options_.coarse_factor % options_.middle_factor != 0)
    throw std::invalid_argument("pattern solve: the coarse block size must be a multiple of the middle one");
  // Where lit pixels can lie: above 90 % of the threshold's share of the peak.
  const double above = 0.9 * level;
  // Block sizes from the coarse one down to the middle one, halving where
  // the halves divide: the local search then steps through each level,
  // a few cells around the coarser level's best, not the middle level's
  // whole reach at once.
  std::vector<int> factors{options_.coarse_factor};
  while (factors.back() > options_.middle_factor) {
    const int half = factors.back() / 2;
    const bool halves = factors.back() % 2 == 0 && half >= options_.middle_factor && half % options_.middle_factor == 0;
    factors.push_back(halves ? half : options_.middle_factor);
  }
  // The template's blocks start where the detector's, at zero shift, do
  // (same pixel phase, so the detector's margin in the template): a block
  // of the image then lies on one cell of the template, not half-way
  // between two (as far as the margins' parity allows).
  const int side_px = template_->sidePx();
  const int margin_u = (side_px - config.detector.width_px) / 2, margin_v = (side_px - config.detector.height_px) / 2;
  for (int factor : factors) {
    Level l;
    l.factor = factor;
    const int origin_u = margin_u % factor, origin_v = margin_v % factor;
    l.cols = (side_px - origin_u) / factor;
    l.rows = (side_px - origin_v) / factor;
    l.step_um = factor * template_->pitchUm();
    l.centre_u = (0.5 * (side_px - 1) - origin_u - 0.5 * (factor - 1)) / factor;
    l.centre_v = (0.5 * (side_px - 1) - origin_v - 0.5 * (factor - 1)) / factor;
    l.values = cv::Mat::zeros(l.rows, l.cols, CV_64F);
    const cv::Mat& p = template_->values();
    for (int v = 0; v < l.rows; ++v)
      for (int u = 0; u < l.cols; ++u) {
        double s = 0.0;
        for (int j = 0; j < factor; ++j)
          for (int i = 0; i < factor; ++i)
            s += std::max(0.0, p.at<double>(origin_v + v * factor + j, origin_u + u * factor + i) - above);
        l.values.at<double>(v, u) = s / (factor * factor);
      }
    cv::integral(l.values, l.integral, CV_64F);
    cv::flip(l.values, l.mirrored, 1);
    levels_.push_back(std::move(l));
  }
}

PatternSolver::~PatternSolver() = default;

Eigen::Vector2d PatternSolver::shiftUm(const Eigen::Vector2d& angles_rad) const {
  const auto spot = drift_.spotPx(0, sunVectorFromAngles(angles_rad.x(), angles_rad.y()));
  return spot ? Eigen::Vector2d(*spot * drift_.pitch_um) : Eigen::Vector2d(1e12, 1e12);
}

Eigen::Vector2d PatternSolver::anglesOfShift(const Eigen::Vector2d& shift_um) const {
  Eigen::Vector2d angles = Eigen::Vector2d::Zero();
  for (int it = 0; it < 20; ++it) {
    constexpr double kStep = 1e-6;
    Eigen::Matrix2d j;
    for (int axis = 0; axis < 2; ++axis) {
      Eigen::Vector2d d = Eigen::Vector2d::Zero();
      d[axis] = kStep;
      j.col(axis) = (shiftUm(angles + d) - shiftUm(angles - d)) / (2.0 * kStep);
    }
    const Eigen::Vector2d step = j.inverse() * (shift_um - shiftUm(angles));
    if (!step.allFinite()) break;
    angles += step;
    if (step.norm() < 1e-13) break;
  }
  return angles;
}

namespace {

// Sums of an image's values over blocks of `factor` x `factor` pixels (the
// blocks at the right and bottom edges cut short), in `Sum`. The values are
// codes or sums of codes: their sums are whole numbers, exact in any order.
// A row of blocks is summed down its columns first (whole rows at a time,
// which the compiler vectorises; per block of two pixels the loop cost more
// than the additions), then across each block, and written once.
template <typename Value, typename Sum>
void blockSums(const cv::Mat& image, int factor, cv::Mat& sums) {
  thread_local std::vector<Sum> column_sums;
  // In a local: a store to an integer column could be image.cols for all
  // the compiler knows, which kept it from vectorising the loops over it.
  const int cols = image.cols;
  column_sums.resize(static_cast<std::size_t>(cols));
  Sum* column = column_sums.data();
  for (int block_row = 0; block_row < sums.rows; ++block_row) {
    std::fill(column_sums.begin(), column_sums.end(), Sum{0});
    for (int r = block_row * factor, r_end = std::min(image.rows, r + factor); r < r_end; ++r) {
      const Value* from = image.ptr<Value>(r);
      for (int c = 0; c < cols; ++c) column[c] += from[c];
    }
    double* to = sums.ptr<double>(block_row);
    // Blocks of two (the finest level from the image, and each level from
    // the one below it) in one loop the compiler vectorises, not a loop per
    // block; the same sums (0 + a + b is a + b for these non-negative values).
    if (factor == 2) {
      const int pairs = cols / 2;
      for (int block = 0; block < pairs; ++block)
        to[block] = static_cast<double>(column[2 * block] + column[2 * block + 1]);
      if (cols % 2 != 0) to[pairs] = static_cast<double>(column[cols - 1]);
      continue;
    }
    for (int c = 0, block = 0; c < cols; ++block) {
      Sum s{0};
      for (const int end = std::min(c + factor, cols); c < end; ++c) s += column[c];
      to[block] = static_cast<double>(s);
    }
  }
}

}  // namespace

void PatternSolver::pixelsOf(const cv::Mat& image, Pixels& px) const {
  if (image.type() != CV_8U && image.type() != CV_16U)
    throw std::invalid_argument("pattern solve: the image is not CV_8U or CV_16U");
  const cv::Mat lit = image > 0;
  cv::Mat near;
  const int band = 2 * options_.dark_band_px + 1;
  cv::dilate(lit, near, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(band, band)));
  px.runs.clear();
  px.widest_run = 0;
  // Finest level first: each coarser one sums the finer one's blocks.
  px.block_sums.resize(levels_.size());
  for (std::size_t l = levels_.size(); l-- > 0;) {
    const int f = levels_[l].factor;
    cv::Mat& sums = px.block_sums[l];
    sums.create((image.rows + f - 1) / f, (image.cols + f - 1) / f, CV_64F);
    if (l + 1 < levels_.size())  // the finer level's sums, summed again
      blockSums<double, double>(px.block_sums[l + 1], f / levels_[l + 1].factor, sums);
    else if (image.type() == CV_8U)
      blockSums<std::uint8_t, std::uint32_t>(image, f, sums);
    else
      blockSums<std::uint16_t, std::uint32_t>(image, f, sums);
  }
  // The local searches' lit groups (the global search, on level 0, skips dark blocks itself).
  px.lit_groups.resize(levels_.size());
  px.lit_groups_first.resize(levels_.size());
  thread_local std::vector<std::pair<int, int>> row_runs;
  for (std::size_t l = 1; l < levels_.size(); ++l) {
    const cv::Mat& sums = px.block_sums[l];
    auto& groups = px.lit_groups[l];
    auto& first = px.lit_groups_first[l];
    groups.clear();
    first.resize(4 * static_cast<std::size_t>(sums.rows) + 1);
    for (int r = 0; r < sums.rows; ++r) {
      const double* row = sums.ptr<double>(r);
      row_runs.clear();
      for (int c = 0; c < sums.cols;) {
        while (c < sums.cols && row[c] == 0.0) ++c;
        if (c == sums.cols) break;
        const int begin = c;
        while (c < sums.cols && row[c] != 0.0) ++c;
        row_runs.emplace_back(begin, c);
      }
      for (int phase = 0; phase < 4; ++phase) {
        first[4 * static_cast<std::size_t>(r) + phase] = static_cast<int>(groups.size());
        const std::size_t row_start = groups.size();
        for (const auto& [begin, end] : row_runs) {
          // The groups of four from `phase` that meet the run.
          const int from = begin - (begin - phase + 4) % 4, to = end + (phase - end % 4 + 4) % 4;
          if (groups.size() > row_start && from <= groups.back().second)
            groups.back().second = to;
          else
            groups.emplace_back(from, to);
        }
      }
    }
    first[4 * static_cast<std::size_t>(sums.rows)] = static_cast<int>(groups.size());
  }

  // Sized first and filled through pointers: a push_back per pixel cost
  // more than the rest of this function. Every element is written below:
  // not cleared first, a resize writes zeros only where the last image had fewer.
  const auto lit_count = static_cast<std::size_t>(cv::countNonZero(lit));
  const auto near_count = static_cast<std::size_t>(cv::countNonZero(near));  // holds every lit pixel
  px.values.resize(near_count);
  px.lit.resize(lit_count);
  px.dark.resize(near_count - lit_count);
  double* value = px.values.data();
  Pixels::Pixel* lit_pixel = px.lit.data();
  Pixels::Pixel* dark_pixel = px.dark.data();
  const bool eight_bit = image.type() == CV_8U;
  std::size_t k = 0;
  double total = 0.0;  // summed here, not in px: a sum in memory is a store and a load per pixel
  for (int r = 0; r < image.rows; ++r)
    forEachRun(near.ptr<std::uint8_t>(r), image.cols, [&](int begin, int end) {
      px.runs.push_back({begin, r, end - begin, k});
      px.widest_run = std::max(px.widest_run, end - begin);
      for (int i = begin; i < end; ++i) {
        const double v = eight_bit ? image.ptr<std::uint8_t>(r)[i] : image.ptr<std::uint16_t>(r)[i];
        value[k++] = v;
        if (v > 0.0) {
          *lit_pixel++ = {i, r, v};
          total += v;
        } else {
          *dark_pixel++ = {i, r, v};
        }
      }
    });
  px.total = total;
}

namespace {

// Four doubles and a comparison's mask of them (GCC's vector extension:
// AVX in the fits' AVX2 clone, two SSE2 halves otherwise).
using Lanes = double __attribute__((vector_size(32)));
using LaneMask = long long __attribute__((vector_size(32)));

inline double laneSum(const Lanes& v) { return (v[0] + v[1]) + (v[2] + v[3]); }

// sum a[i] b[i], i < n, in four lanes (AVX in the AVX2 clones of its
// callers; Eigen's dot, compiled for SSE2, took two lanes and a fixed cost
// per call several times that of thesis_ca's 16-128 products), a[i] being
// 0 where i + first lies outside the runs [begin, end) of whole groups of
// four from `first` (Pixels::lit_groups at first's phase, sorted,
// disjoint): the groups that hold no light are left out. The products are
// at least +0 (block sums, template), so those add nothing to their lanes,
// and every other product keeps its lane and its place in it: the same sum
// to the bit as over every group (28 % of the groups of the rows' lit
// spans on thesis_ca's finest level).
inline double litDot(const double* a, const double* b, int n, const std::pair<int, int>* run,
                     const std::pair<int, int>* runs_end, int first) {
  Lanes sums = {0.0, 0.0, 0.0, 0.0};
  const int groups_end = n / 4 * 4;
  for (; run != runs_end; ++run) {
    const int from = std::max(0, run->first - first), to = std::min(groups_end, run->second - first);
    if (from >= groups_end) break;
    for (int i = from; i < to; i += 4) {
      Lanes x, y;
      std::memcpy(&x, a + i, sizeof x), std::memcpy(&y, b + i, sizeof y);
      sums += x * y;
    }
  }
  double tail = 0.0;
  for (int i = groups_end; i < n; ++i) tail += a[i] * b[i];
  return laneSum(sums) + tail;
}

struct Peak {
  double score;
  int u, v;  // shift in coarse cells
};

}  // namespace

DSS_VECTOR_CLONES
std::optional<PatternSolution> PatternSolver::solve(const cv::Mat& image, const std::optional<AngleWindow>& window,
                                                    const RunnerUpChoice& choose) const {
  thread_local Pixels buffers;  // allocated once per thread, refilled per image
  const Pixels& px = buffers;
  pixelsOf(image, buffers);
  if (px.lit.empty()) return std::nullopt;
  const double window_px = static_cast<double>(image.cols) * image.rows;
  const double mean = px.total / window_px;
  // Normalised correlation of the image's blocks with the level's template
  // at a shift [um]: the light on the template's bright parts less what the
  // template's light in the window would draw at the image's mean level.
  const double half_w = 0.5 * image.cols * config_.detector.pitch_um;
  const double half_h = 0.5 * image.rows * config_.detector.pitch_um;
  // Shifts are whole cells of the level's grid: the image's blocks lie on
  // the cells from that of block (0, 0) on, and a shift's score is one dot
  // product per row of blocks with the template.
  std::vector<std::array<int, 2>> first_cell(levels_.size()), window_cell(levels_.size());
  for (std::size_t level = 0; level < levels_.size(); ++level) {
    const Level& l = levels_[level];
    // Block (0, 0)'s centre [um from the detector centre].
    const double first_x_um = 0.5 * (l.factor - image.cols) * config_.detector.pitch_um;
    const double first_y_um = 0.5 * (l.factor - image.rows) * config_.detector.pitch_um;
    first_cell[level] = {static_cast<int>(std::lround(first_x_um / l.step_um + l.centre_u)),
                         static_cast<int>(std::lround(first_y_um / l.step_um + l.centre_v))};
    window_cell[level] = {static_cast<int>(std::lround(-half_w / l.step_um + l.centre_u + 0.5)),
                          static_cast<int>(std::lround(-half_h / l.step_um + l.centre_v + 0.5))};
  }
  // Scores of the shifts (u_lo + i, v_lo + j), i < nu, j < nv, into
  // scores[j * nu + i]: row by row of the image's blocks, so that each row and
  // the template's rows it meets are read once for all the shifts, not once
  // per shift (each score sums the same per-row dot products in the same
  // order as one shift alone would).
  std::vector<double> scores;
  auto scoreWindow = [&](std::size_t level, int u_lo, int v_lo, int nu, int nv) {
    const Level& l = levels_[level];
    const cv::Mat& sums = px.block_sums[level];
    const int u0 = first_cell[level][0], v0 = first_cell[level][1];
    scores.assign(static_cast<std::size_t>(nu * nv), 0.0);
    if (level == 0) {
      // The global search, every shift of the field: each block that holds
      // light adds its sum times the template cells it meets along a row of
      // shifts, u0 + c - (u_lo + i) for shift i (right to left: the mirrored
      // row read left to right). Its dot products per row of blocks and
      // shift cost more in loop than in products (thesis_ca: 2401 shifts,
      // a quarter of the blocks lit).
      for (int r = 0; r < sums.rows; ++r) {
        const double* image_row = sums.ptr<double>(r);
        for (int c = 0; c < sums.cols; ++c) {
          const double light = image_row[c];
          if (light == 0.0) continue;
          const int cell = u0 + c - u_lo;  // the template column met at shift i: cell - i
          const int i_from = std::max(0, cell - l.cols + 1), i_to = std::min(nu, cell + 1);
          for (int j = 0; j < nv; ++j) {
            const int tv = v0 + r - (v_lo + j);
            if (tv < 0 || tv >= l.rows) continue;
            const double* mirrored = l.mirrored.ptr<double>(tv) + (l.cols - 1 - cell);  // [i]: column cell - i
            double* row_scores = &scores[static_cast<std::size_t>(j * nu)];
            for (int i = i_from; i < i_to; ++i) row_scores[i] += light * mirrored[i];
          }
        }
      }
    } else {
      // The local searches, 9 or 49 shifts: a dot product per row of blocks
      // and shift (scattered as above, the search took longer), over the
      // row's lit blocks (litDot).
      const auto& groups = px.lit_groups[level];
      const auto& groups_first = px.lit_groups_first[level];
      for (int r = 0; r < sums.rows; ++r) {
        const std::size_t at = 4 * static_cast<std::size_t>(r);
        if (groups_first[at] == groups_first[at + 4]) continue;  // a dark row
        for (int j = 0; j < nv; ++j) {
          const int tv = v0 + r - (v_lo + j);
          if (tv < 0 || tv >= l.rows) continue;
          const double* image_row = sums.ptr<double>(r);
          const double* template_row = l.values.ptr<double>(tv);
          for (int i = 0; i < nu; ++i) {
            // Template cell u - shift_u must lie in [0, cols).
            const int shift_u = u_lo + i;
            const int u_from = std::max(u0, shift_u), u_to = std::min(u0 + sums.cols, shift_u + l.cols);
            if (u_to <= u_from) continue;
            const int first = u_from - u0;
            const std::size_t phase = at + static_cast<std::size_t>(first % 4);
            scores[static_cast<std::size_t>(j * nu + i)] +=
                litDot(image_row + first, template_row + (u_from - shift_u), u_to - u_from,
                       groups.data() + groups_first[phase], groups.data() + groups_first[phase + 1], first);
          }
        }
      }
    }
    for (int j = 0; j < nv; ++j)
      for (int i = 0; i < nu; ++i) {
        const int w0 = window_cell[level][0] - (u_lo + i), h0 = window_cell[level][1] - (v_lo + j);
        scores[static_cast<std::size_t>(j * nu + i)] -=
            mean * l.factor * l.factor * l.sum(w0, h0, w0 + image.cols / l.factor, h0 + image.rows / l.factor);
      }
  };
  // Global search over the field's shifts on the coarse grid.
  const Level& coarse = levels_[0];
  const Eigen::Vector2d reach =
      shiftUm({degToRad(config_.fov.alpha_max_deg + 0.5), degToRad(config_.fov.beta_max_deg + 0.5)}).cwiseAbs();
  const int rx = static_cast<int>(std::ceil(reach.x() / coarse.step_um));
  const int ry = static_cast<int>(std::ceil(reach.y() / coarse.step_um));
  const int gw = 2 * rx + 1, gh = 2 * ry + 1;
  scoreWindow(0, -rx, -ry, gw, gh);
  const std::vector<double> map = scores;
  std::vector<Peak> peaks;
  for (int j = 0; j < gh; ++j)
    for (int i = 0; i < gw; ++i) {
      const double s = map[static_cast<std::size_t>(j * gw + i)];
      bool local_max = true;
      for (int dj = -1; dj <= 1 && local_max; ++dj)
        for (int di = -1; di <= 1; ++di) {
          const int ii = i + di, jj = j + dj;
          if ((di || dj) && ii >= 0 && jj >= 0 && ii < gw && jj < gh &&
              map[static_cast<std::size_t>(jj * gw + ii)] > s) {
            local_max = false;
            break;
          }
        }
      if (local_max) peaks.push_back({s, i - rx, j - ry});
    }
  std::sort(peaks.begin(), peaks.end(), [](const Peak& a, const Peak& b) { return a.score > b.score; });
  if (peaks.size() > static_cast<std::size_t>(options_.candidates))
    peaks.resize(static_cast<std::size_t>(options_.candidates));
  std::vector<PatternSolution> fits;
  // Each candidate: the best shift of each finer level around the coarser
  // level's best, down to the middle level; its residual there on a sparse
  // subsample, and the fit where that lies near the best candidate's.
  struct Track {
    int u, v;    // best shift so far, in the current level's cells
    double top;  // its score
  };
  std::vector<Track> tracks;
  for (const auto& peak : peaks) tracks.push_back({peak.u, peak.v, peak.score});
  for (std::size_t level = 1; level < levels_.size(); ++level) {
    // The coarse peak can lie more than a cell off (coarse blocks blur
    // the pattern); a finer level's start lies within a cell. (Of 1200
    // thesis_ca candidates, the best of the 8 px level lay 2 cells off the
    // 16 px level's in 4, the finer levels' never more than 1 cell off
    // the coarser's, from a search of 2 cells.)
    const int ratio = levels_[level - 1].factor / levels_[level].factor;
    const int span = level == 1 ? ratio + 1 : std::max(1, ratio / 2);
    for (Track& t : tracks) {
      const int centre_u = t.u * ratio, centre_v = t.v * ratio;
      scoreWindow(level, centre_u - span, centre_v - span, 2 * span + 1, 2 * span + 1);
      t.top = -std::numeric_limits<double>::infinity();
      for (int j = -span; j <= span; ++j)
        for (int i = -span; i <= span; ++i) {
          const double value = scores[static_cast<std::size_t>((j + span) * (2 * span + 1) + i + span)];
          if (value > t.top) {
            t.top = value;
            t.u = centre_u + i;
            t.v = centre_v + j;
          }
        }
    }
    if (level + 2 == levels_.size() && !tracks.empty()) {
      // Before the finest level (its search costs most): candidates that
      // score well below the best one here are dropped.
      double best = -std::numeric_limits<double>::infinity();
      for (const Track& t : tracks) best = std::max(best, t.top);
      if (best > 0.0)
        tracks.erase(std::remove_if(tracks.begin(), tracks.end(),
                                    [&](const Track& t) { return t.top < kKeepScoreShare * best; }),
                     tracks.end());
    }
  }
  std::vector<Eigen::Vector2d> starts;
  std::vector<double> start_rms;
  for (const Track& t : tracks) {
    const Eigen::Vector2d shift = Eigen::Vector2d(t.u, t.v) * levels_.back().step_um;
    const Eigen::Vector2d start = anglesOfShift(shift);
    const auto at_start = fit(px, start, kScreenStrideFactor * options_.candidate_stride, 0);
    starts.push_back(start);
    start_rms.push_back(at_start ? at_start->residual_rms_dn : std::numeric_limits<double>::infinity());
  }
  const double best_start_rms = starts.empty() ? 0.0 : *std::min_element(start_rms.begin(), start_rms.end());
  for (std::size_t k = 0; k < starts.size(); ++k) {
    if (!(start_rms[k] <= kScreenRatio * best_start_rms)) {
      // Not refined: its residual at the start stands in for its fit's
      // (an upper bound, far above the best's anyway).
      PatternSolution unrefined;
      unrefined.angles_rad = starts[k];
      unrefined.residual_rms_dn = start_rms[k];
      if (std::isfinite(start_rms[k]) && (!window || window->contains(starts[k]))) fits.push_back(unrefined);
      continue;
    }
    const auto solution = fit(px, starts[k], options_.candidate_stride, options_.candidate_iterations);
    if (solution && (!window || window->contains(solution->angles_rad))) fits.push_back(*solution);
  }
  if (fits.empty()) return std::nullopt;
  std::sort(fits.begin(), fits.end(),
            [](const PatternSolution& a, const PatternSolution& b) { return a.residual_rms_dn < b.residual_rms_dn; });
  // The first candidate whose fit on every pixel stays in the window (or
  // the runner-up, where `choose` takes it); the runner-up's residual
  // against the candidate's own on the same subsample.
  for (std::size_t winner = 0; winner < fits.size(); ++winner) {
    const PatternSolution& chosen = fits[winner];
    std::size_t runner_up = fits.size();
    for (std::size_t k = 0; k < fits.size() && runner_up == fits.size(); ++k)
      if (k != winner && (fits[k].angles_rad - chosen.angles_rad).norm() > degToRad(PatternSolution::kDistinctDeg))
        runner_up = k;
    const bool other = runner_up < fits.size() && choose && choose(chosen, fits[runner_up]);
    const PatternSolution& start = other ? fits[runner_up] : chosen;
    // A candidate not refined (screened out) is refined first, on the subsample.
    const auto from = start.gain > 0.0
                          ? std::optional<PatternSolution>(start)
                          : fit(px, start.angles_rad, options_.candidate_stride, options_.candidate_iterations);
    auto best = from ? fit(px, from->angles_rad, 1, options_.iterations, from->gain) : std::nullopt;
    if (!best) continue;
    if (other) {
      best->alternative_rad = chosen.angles_rad;
      best->alternative_cost_ratio = chosen.residual_rms_dn / std::max(start.residual_rms_dn, 1e-30);
      return best;
    }
    if (window && !window->contains(best->angles_rad)) continue;
    if (runner_up < fits.size()) {
      best->alternative_rad = fits[runner_up].angles_rad;
      best->alternative_cost_ratio = fits[runner_up].residual_rms_dn / std::max(chosen.residual_rms_dn, 1e-30);
    }
    return best;
  }
  return std::nullopt;
}

DSS_VECTOR_CLONES
std::optional<PatternSolution> PatternSolver::fit(const Pixels& px, Eigen::Vector2d angles, int stride, int iterations,
                                                  std::optional<double> start_gain) const {
  const auto step_by = static_cast<std::size_t>(std::max(stride, 1));
  const PatternTemplate& p = *template_;
  // The template along a pixel run (stride 1), sized once for the widest:
  // resized per run, each longer run than the last had zeros written first.
  thread_local std::vector<double> t, gx, gy;
  if (t.size() < static_cast<std::size_t>(px.widest_run)) {
    t.resize(static_cast<std::size_t>(px.widest_run));
    gx.resize(t.size()), gy.resize(t.size());
  }
  // The gain that best explains the lit pixels at the start's shift.
  double gain = start_gain.value_or(0.0);
  if (!start_gain) {
    const Eigen::Vector2d d = shiftUm(angles);
    const PatternTemplate::Shifted shifted =
        p.shifted(config_.detector.width_px, config_.detector.height_px, d.x(), d.y());
    double vp = 0.0, pp = 0.0;
    if (step_by == 1) {
      for (const auto& run : px.runs) {
        const auto n = static_cast<std::size_t>(run.count);
        shifted.run(run.col, run.row, run.count, t.data());
        const double* q = &px.values[run.first];
        for (std::size_t i = 0; i < n; ++i)
          if (q[i] > 0.0) vp += (q[i] + offset_) * t[i], pp += t[i] * t[i];
      }
    } else {
      for (std::size_t i = 0; i < px.lit.size(); i += step_by) {
        const auto& q = px.lit[i];
        const double t = shifted.at(q.col, q.row);
        vp += (q.value + offset_) * t;
        pp += t * t;
      }
    }
    if (!(pp > 0.0)) return std::nullopt;
    gain = vp / pp;
  }
  PatternSolution out;
  Eigen::Matrix3d normal = Eigen::Matrix3d::Zero();
  double sse = 0.0;
  int used = 0;
  auto residual_variance = [&] { return sse / std::max(used - 3, 1); };  // per pixel, of the last pass
  for (int it = 0;; ++it) {
    const Eigen::Vector2d d = shiftUm(angles);
    const PatternTemplate::Shifted shifted =
        p.shifted(config_.detector.width_px, config_.detector.height_px, d.x(), d.y());
    Eigen::Matrix2d dd;  // d(shift)/d(angles)
    constexpr double kStep = 1e-6;
    for (int axis = 0; axis < 2; ++axis) {
      Eigen::Vector2d e = Eigen::Vector2d::Zero();
      e[axis] = kStep;
      dd.col(axis) = (shiftUm(angles + e) - shiftUm(angles - e)) / (2.0 * kStep);
    }
    // The normal matrix's six entries and the gradient as plain sums: the
    // per-pixel 3 x 3 outer product through Eigen spilled to the stack.
    double n00 = 0.0, n01 = 0.0, n02 = 0.0, n11 = 0.0, n12 = 0.0, n22 = 0.0, g0 = 0.0, g1 = 0.0, g2 = 0.0;
    sse = 0.0;
    used = 0;
    // A pixel of value q, lit or not, where the template reads t with gradient (gx, gy).
    auto add = [&](double q, bool lit, double t, double gx, double gy) {
      const double predicted = gain * t - offset_;
      if (!lit && !(predicted > floor_)) return;          // censored: dark, and predicted so
      if (lit && q >= top_ && predicted >= top_) return;  // saturated, and predicted so
      const double residual = (lit ? q : floor_) - predicted;
      // d(predicted)/d(angles) = -gain grad P . d(shift)/d(angles)
      const double ja = -gain * (dd(0, 0) * gx + dd(1, 0) * gy), jb = -gain * (dd(0, 1) * gx + dd(1, 1) * gy);
      n00 += ja * ja, n01 += ja * jb, n02 += ja * t, n11 += jb * jb, n12 += jb * t, n22 += t * t;
      g0 += ja * residual, g1 += jb * residual, g2 += t * residual;
      sse += residual * residual;
      ++used;
    };
    if (step_by == 1) {
      // add()'s terms, four pixels at a time in four lanes of sums (the
      // pass on every pixel is most of the fits' work; a pixel add() skips
      // adds zeros), the runs' last few through add() itself. The sums'
      // order differs: on 2700 thesis_ca images the same statuses and
      // estimates to the CSV's ten digits, 3 sigmas moved in the tenth.
      const Lanes zero = {0.0, 0.0, 0.0, 0.0}, one = {1.0, 1.0, 1.0, 1.0};
      Lanes l00 = zero, l01 = zero, l02 = zero, l11 = zero, l12 = zero, l22 = zero;
      Lanes lg0 = zero, lg1 = zero, lg2 = zero, lsse = zero, lused = zero;
      for (const auto& run : px.runs) {
        const auto n = static_cast<std::size_t>(run.count);
        shifted.run(run.col, run.row, run.count, t.data(), gx.data(), gy.data());
        const double* q = &px.values[run.first];
        std::size_t i = 0;
        for (; i + 4 <= n; i += 4) {
          Lanes qv, tv, gxv, gyv;
          std::memcpy(&qv, q + i, sizeof qv), std::memcpy(&tv, &t[i], sizeof tv);
          std::memcpy(&gxv, &gx[i], sizeof gxv), std::memcpy(&gyv, &gy[i], sizeof gyv);
          const Lanes predicted = gain * tv - offset_;
          const LaneMask lit = qv > zero;
          const LaneMask use = lit ? ~((qv >= top_) & (predicted >= top_)) : predicted > floor_;
          const Lanes residual = use ? (lit ? qv : zero + floor_) - predicted : zero;
          const Lanes ja = use ? -gain * (dd(0, 0) * gxv + dd(1, 0) * gyv) : zero;
          const Lanes jb = use ? -gain * (dd(0, 1) * gxv + dd(1, 1) * gyv) : zero;
          const Lanes tu = use ? tv : zero;
          l00 += ja * ja, l01 += ja * jb, l02 += ja * tu, l11 += jb * jb, l12 += jb * tu, l22 += tu * tu;
          lg0 += ja * residual, lg1 += jb * residual, lg2 += tu * residual;
          lsse += residual * residual;
          lused += use ? one : zero;
        }
        for (; i < n; ++i) add(q[i], q[i] > 0.0, t[i], gx[i], gy[i]);
      }
      n00 += laneSum(l00), n01 += laneSum(l01), n02 += laneSum(l02), n11 += laneSum(l11), n12 += laneSum(l12);
      n22 += laneSum(l22), g0 += laneSum(lg0), g1 += laneSum(lg1), g2 += laneSum(lg2), sse += laneSum(lsse);
      used += static_cast<int>(laneSum(lused));
    } else {
      auto visit = [&](const Pixels::Pixel& q, bool lit) {
        // Most dark pixels are censored: their value alone decides.
        if (!lit && !(gain * shifted.at(q.col, q.row) - offset_ > floor_)) return;
        double gx, gy;
        const double t = shifted.at(q.col, q.row, gx, gy);
        add(q.value, lit, t, gx, gy);
      };
      for (std::size_t i = 0; i < px.lit.size(); i += step_by) visit(px.lit[i], true);
      for (std::size_t i = 0; i < px.dark.size(); i += step_by) visit(px.dark[i], false);
    }
    normal << n00, n01, n02, n01, n11, n12, n02, n12, n22;
    const Eigen::Vector3d gradient(g0, g1, g2);
    out.iterations = it;
    if (it == iterations || used < 4) break;
    const Eigen::Vector3d step = normal.ldlt().solve(gradient);
    if (!step.allFinite()) return std::nullopt;
    angles += step.head<2>();
    gain += step[2];
    // Each step is 15-40 times smaller than the one before: after one below
    // 30 % of the solution's sigma (or 1e-8 rad) the solution lies within
    // about 2 % of it, and this pass's normal matrix and residual stand
    // for the solution's (another pass would change them by the step's
    // square). On 40 thesis_ca images the fit on every pixel, from its
    // candidate's on the subsample, stepped 0.36-5.4 sigma, then
    // 0.006-0.38, then 0.0002-0.03: it stops after two passes, not three.
    const Eigen::Matrix3d pass_inverse = normal.inverse();
    const double sigma_min = std::sqrt(residual_variance() * std::min(pass_inverse(0, 0), pass_inverse(1, 1)));
    if (step.head<2>().norm() < std::max(1e-8, kConvergedSigmaShare * sigma_min)) {
      out.iterations = it + 1;
      break;
    }
  }
  if (used < 4 || !angles.allFinite()) return std::nullopt;
  const Eigen::Matrix3d inverse = normal.inverse();
  if (!inverse.allFinite()) return std::nullopt;
  out.angles_rad = angles;
  out.covariance = residual_variance() * inverse.topLeftCorner<2, 2>();
  out.gain = gain;
  out.residual_rms_dn = std::sqrt(sse / used);
  out.pixels = used;
  return out;
}

}  // namespace dss
