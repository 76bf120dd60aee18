#include "digital_sun_sensor/baseline/design_canvases.h"

#include <Eigen/LU>
#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <stdexcept>
#include <thread>

#include "digital_sun_sensor/common/cubic_weights.h"
#include "digital_sun_sensor/common/row_runs.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/common/vector_clones.h"
#include "digital_sun_sensor/sim/geometry.h"
#include "digital_sun_sensor/sim/readout.h"
#include "digital_sun_sensor/sim/spot_cache.h"

namespace dss {

struct DesignCanvases::Canvas {
  cv::Mat rate;        // optical photoelectrons per second (CV_32F), the wide detector
  int drift_x_px = 0;  // where its spots lie: drifted by whole pixels from
  int drift_y_px = 0;  // the apertures (every canvas at the same phase)
};

namespace {

// to[i] = sum over k < N of weights[k] from[k][i], in order of k.
template <int N>
void blendRow(const std::array<const float*, 4>& from, const std::array<float, 4>& weights, int count, float* to) {
  for (int i = 0; i < count; ++i) {
    float v = weights[0] * from[0][i];
    for (int k = 1; k < N; ++k) v += weights[k] * from[k][i];
    to[i] = v;
  }
}

DSS_VECTOR_CLONES
void blendRow(const std::array<const float*, 4>& from, const std::array<float, 4>& weights, int n, int count,
              float* to) {
  switch (n) {
    case 1:
      return blendRow<1>(from, weights, count, to);
    case 2:
      return blendRow<2>(from, weights, count, to);
    case 3:
      return blendRow<3>(from, weights, count, to);
    default:
      return blendRow<4>(from, weights, count, to);
  }
}

using FloatLanes = float __attribute__((vector_size(32)));

// out[i] = the bicubic read of the four rows at columns i .. i + 3, at
// least 0 (no undershoot below dark); returns the largest of them and `peak`.
DSS_VECTOR_CLONES
float bicubicRun(const std::array<const float*, 4>& rows, const std::array<float, 4>& wu,
                 const std::array<float, 4>& wv, int count, float* out, float peak) {
  const float *r0 = rows[0], *r1 = rows[1], *r2 = rows[2], *r3 = rows[3];
  for (int i = 0; i < count; ++i) {
    const float a = wu[0] * r0[i] + wu[1] * r0[i + 1] + wu[2] * r0[i + 2] + wu[3] * r0[i + 3];
    const float b = wu[0] * r1[i] + wu[1] * r1[i + 1] + wu[2] * r1[i + 2] + wu[3] * r1[i + 3];
    const float c = wu[0] * r2[i] + wu[1] * r2[i + 1] + wu[2] * r2[i + 2] + wu[3] * r2[i + 3];
    const float d = wu[0] * r3[i] + wu[1] * r3[i + 1] + wu[2] * r3[i + 2] + wu[3] * r3[i + 3];
    out[i] = std::max(0.0f, wv[0] * a + wv[1] * b + wv[2] * c + wv[3] * d);
  }
  // The largest in eight lanes (a maximum in any order is the same).
  FloatLanes lanes = {peak, peak, peak, peak, peak, peak, peak, peak};
  int i = 0;
  for (; i + 8 <= count; i += 8) {
    FloatLanes v;
    __builtin_memcpy(&v, out + i, sizeof v);
    lanes = lanes > v ? lanes : v;
  }
  for (int k = 0; k < 8; ++k) peak = std::max(peak, lanes[k]);
  for (; i < count; ++i) peak = std::max(peak, out[i]);
  return peak;
}

}  // namespace

DesignCanvases::DesignCanvases(const Renderer& design, double margin_deg) : design_(design) {
  const SensorConfig& c = design.config();
  const bool far_field = design.spotCache().path().mode == OpticsMode::kFarField;
  step_rad_ = far_field ? 0.0 : degToRad(c.optics.psf_node_step_deg);
  const double alpha_max = degToRad(c.fov.alpha_max_deg + margin_deg);
  const double beta_max = degToRad(c.fov.beta_max_deg + margin_deg);
  if (!far_field) {
    // An incidence within them blends the nodes floor(angle / step) and the one after.
    const auto reach = [this](double max_rad) {
      return std::max(-static_cast<int>(std::floor(-max_rad / step_rad_)),
                      static_cast<int>(std::floor(max_rad / step_rad_)) + 1);
    };
    nodes_x_ = reach(alpha_max);
    nodes_y_ = reach(beta_max);
  }
  // How far an incidence a node serves (its four cells; the whole field in
  // the far field) moves the spots from where the node's canvas has them.
  double reach_px = 0.0;
  const double pitch = c.detector.pitch_um;
  if (far_field) {
    for (double a : {-alpha_max, alpha_max})
      for (double b : {-beta_max, beta_max})
        reach_px = std::max(reach_px, driftUm(sunVectorFromAngles(a, b)).cwiseAbs().maxCoeff() / pitch);
  } else {
    for (int iy = -nodes_y_; iy <= nodes_y_; ++iy)
      for (int ix = -nodes_x_; ix <= nodes_x_; ++ix) {
        const Eigen::Vector2d at = driftUm(sunVectorFromAngles(ix * step_rad_, iy * step_rad_));
        for (int dy = -1; dy <= 1; ++dy)
          for (int dx = -1; dx <= 1; ++dx) {
            const Eigen::Vector2d near = driftUm(sunVectorFromAngles((ix + dx) * step_rad_, (iy + dy) * step_rad_));
            reach_px = std::max(reach_px, (near - at).cwiseAbs().maxCoeff() / pitch);
          }
      }
  }
  margin_px_ = static_cast<int>(std::ceil(reach_px + 0.5)) + 3;  // whole-pixel placement, the bicubic taps
  SensorConfig wide = c;
  wide.detector.width_px += 2 * margin_px_;
  wide.detector.height_px += 2 * margin_px_;
  wide_ = std::make_unique<Renderer>(SensorInstance::nominalOf(wide));
  readout_ = std::make_unique<NoiseFreeReadout>(c, true);
  const std::size_t nodes = static_cast<std::size_t>(2 * nodes_x_ + 1) * (2 * nodes_y_ + 1);
  canvases_.resize(nodes);
  built_ = std::vector<std::once_flag>(nodes);
}

DesignCanvases::~DesignCanvases() = default;

Eigen::Vector2d DesignCanvases::driftUm(const Eigen::Vector3d& sun) const {
  const SensorConfig& c = design_.config();
  const GlassSlab glass{c.cover_glass.enabled ? c.cover_glass.thickness_mm * 1000.0 : 0.0,
                        design_.spotCache().path().glass_index};
  const Eigen::Vector3d aperture = design_.instance().apertureCentreUm(0);
  const auto hit = traceToDetector(aperture, sun, glass);
  if (!hit) return Eigen::Vector2d::Constant(std::numeric_limits<double>::infinity());
  return *hit - aperture.head<2>();
}

const DesignCanvases::Canvas& DesignCanvases::canvas(int ix, int iy) const {
  const std::size_t index = static_cast<std::size_t>(iy + nodes_y_) * (2 * nodes_x_ + 1) + (ix + nodes_x_);
  std::call_once(built_[index], [&] {
    const Eigen::Vector2d node(ix * step_rad_, iy * step_rad_);
    const Eigen::Vector3d shape = sunVectorFromAngles(node.x(), node.y());
    // The spots placed by the direction nearest the node's whose drift is
    // whole pixels (Newton's method on the trace), so that every canvas
    // shares one sub-pixel phase and an image blends them before a single
    // interpolation.
    const double pitch = design_.config().detector.pitch_um;
    const Eigen::Vector2d target = (driftUm(shape) / pitch).array().round();
    Eigen::Vector2d place = node;
    for (int iteration = 0; iteration < 20; ++iteration) {
      const Eigen::Vector2d miss = driftUm(sunVectorFromAngles(place.x(), place.y())) / pitch - target;
      if (miss.cwiseAbs().maxCoeff() < 1e-9) break;
      constexpr double kStepRad = 1e-7;
      Eigen::Matrix2d jacobian;
      for (int k = 0; k < 2; ++k) {
        Eigen::Vector2d moved = place;
        moved[k] += kStepRad;
        jacobian.col(k) = (driftUm(sunVectorFromAngles(moved.x(), moved.y())) / pitch - target - miss) / kStepRad;
      }
      place -= jacobian.lu().solve(miss);
    }
    auto canvas = std::make_unique<Canvas>();
    const Eigen::Vector2d miss = driftUm(sunVectorFromAngles(place.x(), place.y())) / pitch - target;
    if (!(miss.cwiseAbs().maxCoeff() < 1e-6)) {  // no such direction found: images there are rendered
      canvases_[index] = std::move(canvas);
      return;
    }
    ImageTruth truth;
    const cv::Mat electrons =
        wide_->expectedElectrons(sunVectorFromAngles(place.x(), place.y()), &truth, nullptr, nullptr, &shape);
    canvas->rate = truth.exposure_s > 0.0 ? cv::Mat(electrons / truth.exposure_s) : electrons;
    canvas->drift_x_px = static_cast<int>(target.x());
    canvas->drift_y_px = static_cast<int>(target.y());
    bytes_ += canvas->rate.total() * canvas->rate.elemSize();
    canvases_[index] = std::move(canvas);
  });
  return *canvases_[index];
}

void DesignCanvases::warmUp(int threads) const {
  std::atomic<std::size_t> next{0};
  auto work = [&] {
    for (std::size_t i; (i = next++) < canvases_.size();) {
      const int row = static_cast<int>(i) / (2 * nodes_x_ + 1), col = static_cast<int>(i) % (2 * nodes_x_ + 1);
      canvas(col - nodes_x_, row - nodes_y_);
    }
  };
  std::vector<std::thread> pool;
  for (int t = 1; t < threads; ++t) pool.emplace_back(work);
  work();
  for (auto& t : pool) t.join();
}

std::size_t DesignCanvases::bytesHeld() const { return bytes_; }

std::size_t DesignCanvases::bytesWhole() const {
  const SensorConfig& c = wide_->config();
  return canvases_.size() * static_cast<std::size_t>(c.detector.width_px) * c.detector.height_px * sizeof(float);
}

std::optional<cv::Mat> DesignCanvases::image(const Eigen::Vector2d& angles_rad, const cv::Mat* only) const {
  const SensorConfig& c = design_.config();
  const int w = c.detector.width_px, h = c.detector.height_px;
  if (only && (only->rows != h || only->cols != w || only->type() != CV_8U))
    throw std::invalid_argument(
        "design canvases: the mask of pixels to light is not a CV_8U image of the detector's size");
  const Eigen::Vector3d sun = sunVectorFromAngles(angles_rad.x(), angles_rad.y());
  // The nodes and their weights as the renderer blends their spot shapes.
  const SpotCache::NodeBlend nodes = design_.spotCache().nodesOf(sun);
  for (int k = 0; k < nodes.count; ++k)
    if (std::abs(nodes.nodes[k].ix) > nodes_x_ || std::abs(nodes.nodes[k].iy) > nodes_y_) return std::nullopt;
  const int count = nodes.count;
  const Eigen::Vector2d drift = driftUm(sun);
  if (!drift.allFinite()) return std::nullopt;
  // Pixel (col, row) reads canvas k at (col + u + drift_x_px, row + v + drift_y_px):
  // one sub-pixel phase for all of them.
  const double u = margin_px_ - drift.x() / c.detector.pitch_um, v = margin_px_ - drift.y() / c.detector.pitch_um;
  const double fu = std::floor(u), fv = std::floor(v);
  double wu_d[4], wv_d[4], unused[4];
  cubicWeights(u - fu, wu_d, unused);
  cubicWeights(v - fv, wv_d, unused);
  std::array<float, 4> wu, wv, blend_weights;
  for (int j = 0; j < 4; ++j) wu[j] = static_cast<float>(wu_d[j]), wv[j] = static_cast<float>(wv_d[j]);
  std::array<const Canvas*, 4> canvases{};
  std::array<int, 4> base_u{}, base_v{};  // canvas k's column and row of the blend's (0, 0)
  for (int k = 0; k < count; ++k) {
    const Canvas& canvas = this->canvas(nodes.nodes[k].ix, nodes.nodes[k].iy);
    if (canvas.rate.empty()) return std::nullopt;
    canvases[k] = &canvas;
    blend_weights[k] = nodes.nodes[k].weight;
    base_u[k] = static_cast<int>(fu) - 1 + canvas.drift_x_px;
    base_v[k] = static_cast<int>(fv) - 1 + canvas.drift_y_px;
    if (base_u[k] < 0 || base_v[k] < 0 || base_u[k] + w + 3 > canvas.rate.cols || base_v[k] + h + 3 > canvas.rate.rows)
      return std::nullopt;
  }

  // The marked pixels' runs, row by row, and each row's span of them [first,
  // last); the blend's row t is read by the image's rows t - 3 .. t, over
  // the union of their spans.
  struct Run {
    int row, begin, end;
  };
  thread_local std::vector<Run> runs;
  thread_local std::vector<std::pair<int, int>> span;
  runs.clear();
  span.assign(static_cast<std::size_t>(h), {w, 0});
  for (int r = 0; r < h; ++r) {
    if (!only) {
      runs.push_back({r, 0, w});
      span[r] = {0, w};
      continue;
    }
    forEachRun(only->ptr<std::uint8_t>(r), w, [&](int begin, int end) {
      runs.push_back({r, begin, end});
      span[r].first = std::min(span[r].first, begin);
      span[r].second = std::max(span[r].second, end);
    });
  }
  thread_local cv::Mat rate, blended;  // what no marked pixel reads is left as it was
  rate.create(h, w, CV_32F);
  blended.create(4, w + 3, CV_32F);  // the blend's rows t (in row t % 4), columns 0 .. w + 2
  int next_blended = 0;
  const auto blendUpTo = [&](int last) {
    for (; next_blended <= last; ++next_blended) {
      const int t = next_blended;
      int from = w, to = 0;
      for (int r = std::max(0, t - 3); r <= std::min(h - 1, t); ++r)
        if (span[r].first < span[r].second) from = std::min(from, span[r].first), to = std::max(to, span[r].second + 3);
      if (from >= to) continue;
      std::array<const float*, 4> rows{};
      for (int k = 0; k < count; ++k) rows[k] = canvases[k]->rate.ptr<float>(base_v[k] + t) + base_u[k] + from;
      blendRow(rows, blend_weights, count, to - from, blended.ptr<float>(t % 4) + from);
    }
  };
  float peak_rate = 0.0f;
  for (const Run& run : runs) {
    blendUpTo(run.row + 3);
    std::array<const float*, 4> rows;
    for (int j = 0; j < 4; ++j) rows[j] = blended.ptr<float>((run.row + j) % 4) + run.begin;
    peak_rate = bicubicRun(rows, wu, wv, run.end - run.begin, rate.ptr<float>(run.row) + run.begin, peak_rate);
  }
  // Exposure and detector as Renderer::render's for the design.
  double exposure_s = c.exposure.exposure_s;
  if (c.exposure.mode == ExposureMode::kAuto && peak_rate > 0.0f)
    exposure_s = c.exposure.peak_fraction_of_full_well * c.noise.full_well_e / peak_rate;
  // Codes as Renderer::detect's without noise (no dark electrons): the
  // marked pixels' light through the readout, every other pixel unlit (as
  // are the marked ones below NoiseFreeReadout::unlitBelowE, converted
  // nonetheless: one vectorised pass cost less than the branch per pixel).
  cv::Mat codes(h, w, CV_16U);
  std::fill_n(codes.ptr<std::uint16_t>(), codes.total(), static_cast<std::uint16_t>(readout_->unlitCode(0.0)));
  for (const Run& run : runs)
    readout_->codes(rate.ptr<float>(run.row) + run.begin, static_cast<float>(exposure_s), c.noise.full_well_e,
                    run.end - run.begin, codes.ptr<std::uint16_t>(run.row) + run.begin);
  return codes;
}

}  // namespace dss
