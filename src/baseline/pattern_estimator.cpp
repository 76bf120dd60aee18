#include "digital_sun_sensor/baseline/pattern_estimator.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <stdexcept>
#include <string>

#include "digital_sun_sensor/baseline/calibration_model.h"
#include "digital_sun_sensor/common/estimate_status.h"
#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/common/row_runs.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/sim/geometry.h"
#include "digital_sun_sensor/sim/readout.h"
#include "digital_sun_sensor/sim/renderer.h"

namespace dss {

PatternEstimator::PatternEstimator(const SensorConfig& config, const PatternEstimatorOptions& options)
    : config_(config),
      input_(inputSpecFor(config)),
      solver_(config),
      design_(SensorInstance::nominalOf(config)),
      noise_(config, config.exposure.exposure_s),
      geometry_(MaskGeometry::nominalOf(config)) {
  const Eigen::Vector2d half(degToRad(config.fov.alpha_max_deg + kFieldMarginDeg),
                             degToRad(config.fov.beta_max_deg + kFieldMarginDeg));
  field_ = {-half, half};
  if (options.design_canvases) {
    canvases_ = std::make_unique<DesignCanvases>(design_, kFieldMarginDeg);
    if (canvases_->bytesWhole() > kMaxDesignCanvasBytes) canvases_.reset();  // a wide field: every image rendered
  }
  // The design's pixels read as lit from this share of its brightest on
  // (auto exposure under an on-chip threshold; else each decision renders
  // the whole detector).
  const double peak_code =
      std::min<double>(config.maxCode(), config.exposure.peak_fraction_of_full_well * config.noise.full_well_e *
                                                 config.maxCode() / config.noise.adc_full_scale_e +
                                             config.noise.black_level_dn);
  const double lit_share = (config.threshold.level_fraction * config.maxCode() - config.noise.black_level_dn) /
                           (peak_code - config.noise.black_level_dn);
  if (config.exposure.mode == ExposureMode::kAuto && config.threshold.enabled && lit_share > 0.0 && lit_share < 1.0)
    reach_.emplace(solver_.patternTemplate(), kReachMargin * lit_share);
  // Image values are codes: their variances and linear range once per code.
  for (int code = 0; code <= config.maxCode(); ++code)
    linear_code_.push_back(noise_.inLinearRange(code, kLinearRangeSigmas));
  for (int sum = 0; sum <= 2 * config.maxCode(); ++sum)
    variance_of_half_sum_.push_back(noise_.varianceOfValue(0.5 * sum));
  // The code of a design pixel that holds no light (the noise-free detector's, no dark electrons).
  unlit_code_ = static_cast<std::uint16_t>(NoiseFreeReadout(config, true).unlitCode(0.0));
  if (options.sigma_images <= 0) return;
  // The design with its detector's fixed patterns and noise, no unit errors, no anomalies.
  SensorConfig design = config;
  design.as_built = AsBuiltConfig{};
  design.anomalies = AnomalyConfig{};
  design.anomalies.hot_pixel_count = 0;
  const Renderer renderer(SensorInstance::draw(design, options.sigma_seed));
  Rng rng(deriveSeed(options.sigma_seed, 0x51C));
  std::array<double, 2> z2{0.0, 0.0};
  int count = 0;
  for (int k = 0; k < options.sigma_images; ++k) {
    const Eigen::Vector2d truth(degToRad(config.fov.alpha_max_deg) * rng.uniform(-1.0, 1.0),
                                degToRad(config.fov.beta_max_deg) * rng.uniform(-1.0, 1.0));
    const cv::Mat image =
        renderer.render(sunVectorFromAngles(truth.x(), truth.y()), deriveSeed(options.sigma_seed, k), nullptr);
    const auto s = solver_.solve(image, quadrantWindow(quadrantClass(truth.x(), truth.y())));
    if (!s || !(s->covariance(0, 0) > 0.0) || !(s->covariance(1, 1) > 0.0)) continue;
    const Eigen::Vector2d error = s->angles_rad - truth;
    if (error.norm() > degToRad(0.1)) continue;  // a wrong shift, not noise
    z2[0] += error.x() * error.x() / s->covariance(0, 0);
    z2[1] += error.y() * error.y() / s->covariance(1, 1);
    ++count;
  }
  if (count >= options.sigma_images / 2) sigma_scale_ = {std::sqrt(z2[0] / count), std::sqrt(z2[1] / count)};
}

std::optional<cv::Mat> PatternEstimator::designPixels(const cv::Mat& image,
                                                      const std::vector<Eigen::Vector2d>& places_rad) const {
  if (!reach_) return std::nullopt;
  cv::Mat mask = image > 0;
  for (const auto& place : places_rad) {
    const Eigen::Vector2d shift = solver_.shiftUm(place);
    reach_->mark(mask, shift.x(), shift.y());
  }
  return mask;
}

std::vector<cv::Mat> PatternEstimator::designImages(const std::vector<Eigen::Vector2d>& places_rad,
                                                    std::optional<cv::Mat>& pixels) const {
  std::vector<cv::Mat> images;
  for (const auto& place : places_rad) images.push_back(designImage(place, pixels));
  if (pixels && lightsEdge(images, *pixels)) {
    pixels.reset();
    for (std::size_t k = 0; k < places_rad.size(); ++k) images[k] = designImage(places_rad[k], std::nullopt);
  }
  return images;
}

bool PatternEstimator::lightsEdge(const std::vector<cv::Mat>& images, const cv::Mat& pixels) const {
  // A design image lighting a pixel on their edge: its light may go on beyond them.
  struct EdgeRun {
    int row, begin, end;
  };
  std::vector<EdgeRun> edge;
  forEachEdgeRun(pixels.ptr<std::uint8_t>(), pixels.rows, pixels.cols, pixels.step[0], [&](int r, int begin, int end) {
    edge.push_back({r, begin, end});
  });
  for (const cv::Mat& image : images)
    for (const EdgeRun& run : edge) {
      const std::uint16_t* values = image.ptr<std::uint16_t>(run.row);
      if (std::any_of(values + run.begin, values + run.end, [&](std::uint16_t v) { return v != unlit_code_; }))
        return true;
    }
  return false;
}

namespace {

// An image's codes as CV_16U: the image itself where it is one (the
// decisions below read codes, which doubles would only copy).
cv::Mat codesOf(const cv::Mat& image) {
  if (image.depth() == CV_16U) return image;
  cv::Mat out;
  image.convertTo(out, CV_16U);
  return out;
}

}  // namespace

cv::Mat PatternEstimator::designImage(const Eigen::Vector2d& angles_rad, const std::optional<cv::Mat>& only) const {
  RenderOptions options;
  options.noise = false;
  options.anomalies = false;
  options.only = only ? &*only : nullptr;
  return codesOf(design_.render(sunVectorFromAngles(angles_rad.x(), angles_rad.y()), 1, nullptr, options));
}

namespace {

// Calls visit(row, begin, end) per run of the pixels `marked` holds (every
// row whole without it), in raster order.
template <typename Visit>
void forEachMarkedRun(const std::optional<cv::Mat>& marked, int rows, int cols, Visit&& visit) {
  for (int r = 0; r < rows; ++r) {
    if (marked)
      forEachRun(marked->ptr<std::uint8_t>(r), cols, [&](int begin, int end) { visit(r, begin, end); });
    else
      visit(r, 0, cols);
  }
}

}  // namespace

double PatternEstimator::unexplainedLightZ(const cv::Mat& observed, const cv::Mat& expected,
                                           const std::optional<cv::Mat>& pixels) const {
  double chi2 = 0.0;
  int n = 0;
  // Off the rendered pixels the design reads its unlit code; where that lies
  // outside the linear range, they add nothing and are not read.
  const std::optional<cv::Mat>& read = linear_code_[unlit_code_] ? std::nullopt : pixels;
  forEachMarkedRun(read, observed.rows, observed.cols, [&](int r, int begin, int end) {
    const std::uint16_t* i = observed.ptr<std::uint16_t>(r);
    const std::uint16_t* e = expected.ptr<std::uint16_t>(r);
    for (int c = begin; c < end; ++c) {
      if (linear_code_[e[c]]) {
        const double d = static_cast<double>(i[c]) - e[c];
        chi2 += d * d / variance_of_half_sum_[2 * e[c]];
        ++n;
      }
    }
  });
  return n > 0 ? (chi2 - n) / std::sqrt(2.0 * n) : 0.0;
}

double PatternEstimator::unexplainedLightZ(const cv::Mat& image, const Eigen::Vector2d& angles_rad) const {
  std::optional<cv::Mat> pixels = designPixels(image, {angles_rad});
  const cv::Mat observed = codesOf(image);
  if (const auto quick = canvasImages({angles_rad}, pixels)) {
    const double z = unexplainedLightZ(observed, (*quick)[0], pixels);
    if (z <= kCanvasMaxUnexplainedZ) return z;
  }
  const cv::Mat expected = designImages({angles_rad}, pixels)[0];
  return unexplainedLightZ(observed, expected, pixels);
}

AliasEvidence PatternEstimator::evidenceOf(const cv::Mat& observed, const cv::Mat& here, const cv::Mat& there,
                                           const std::optional<cv::Mat>& pixels) const {
  // The log-likelihood ratio of the two places under Gaussian pixel noise
  // (sum of (I - T)^2 / v - (I - H)^2 / v) and its variance under either,
  // 4 sum (H - T)^2 / v; off the rendered pixels both read the unlit code.
  double log_ratio = 0.0, log_ratio_variance = 0.0;
  forEachMarkedRun(pixels, observed.rows, observed.cols, [&](int r, int begin, int end) {
    const std::uint16_t* i = observed.ptr<std::uint16_t>(r);
    const std::uint16_t* h = here.ptr<std::uint16_t>(r);
    const std::uint16_t* t = there.ptr<std::uint16_t>(r);
    for (int c = begin; c < end; ++c) {
      if (h[c] == t[c]) continue;
      const double delta = static_cast<double>(h[c]) - t[c];
      const double rh = static_cast<double>(i[c]) - h[c], rt = static_cast<double>(i[c]) - t[c];
      const double v = variance_of_half_sum_[static_cast<std::size_t>(h[c] + t[c])];
      log_ratio += (rt * rt - rh * rh) / v;
      log_ratio_variance += 4.0 * delta * delta / v;
    }
  });
  AliasEvidence e;
  if (log_ratio_variance > 0.0) e.z = log_ratio / std::sqrt(log_ratio_variance);
  e.unexplained_z = unexplainedLightZ(observed, e.z >= 0.0 ? here : there, pixels);
  return e;
}

std::optional<std::vector<cv::Mat>> PatternEstimator::canvasImages(const std::vector<Eigen::Vector2d>& places_rad,
                                                                   const std::optional<cv::Mat>& pixels) const {
  if (!canvases_) return std::nullopt;
  std::vector<cv::Mat> images;
  for (const auto& place : places_rad) {
    std::optional<cv::Mat> image = canvases_->image(place, pixels ? &*pixels : nullptr);
    if (!image) return std::nullopt;
    images.push_back(std::move(*image));
  }
  if (pixels && lightsEdge(images, *pixels)) return std::nullopt;
  return images;
}

AliasEvidence PatternEstimator::aliasEvidence(const cv::Mat& image, const Eigen::Vector2d& here_rad,
                                              const Eigen::Vector2d& there_rad) const {
  std::optional<cv::Mat> pixels = designPixels(image, {here_rad, there_rad});
  const cv::Mat observed = codesOf(image);
  // The canvases' images decide where they do so by margins that cover
  // their difference from rendered ones: the decision, and the variance
  // inflation of 1, that rendered images would give.
  if (const auto quick = canvasImages({here_rad, there_rad}, pixels)) {
    const AliasEvidence e = evidenceOf(observed, (*quick)[0], (*quick)[1], pixels);
    if (std::abs(e.z) >= AliasEvidence::kMinZ + kCanvasZMargin && e.unexplained_z <= kCanvasMaxUnexplainedZ) return e;
  }
  const std::vector<cv::Mat> designs = designImages({here_rad, there_rad}, pixels);
  return evidenceOf(observed, designs[0], designs[1], pixels);
}

AngleWindow PatternEstimator::quadrantWindow(int quadrant) const {
  const double margin = degToRad(kFieldMarginDeg);
  AngleWindow window = field_;
  if (quadrant & 1)
    window.min_rad.x() = -margin;
  else
    window.max_rad.x() = margin;
  if (quadrant & 2)
    window.min_rad.y() = -margin;
  else
    window.max_rad.y() = margin;
  return window;
}

std::vector<SunEstimate> PatternEstimator::estimate(const std::vector<cv::Mat>& images) {
  std::vector<SunEstimate> out;
  out.reserve(images.size());
  for (const auto& image : images) out.push_back(estimateOne(image));
  return out;
}

std::vector<SunEstimate> PatternEstimator::estimateWithSubFovHints(const std::vector<cv::Mat>& images,
                                                                   const std::vector<int>& subfov_classes) {
  if (subfov_classes.size() != images.size())
    throw std::invalid_argument("pattern estimator: " + std::to_string(subfov_classes.size()) + " sub-FOV hints for " +
                                std::to_string(images.size()) + " images");
  if (config_.subfov != SubFovType::kQuadrant)
    throw std::invalid_argument("pattern estimator: sub-FOV hints are quadrants; sensor '" + config_.name +
                                "' names its sub-FOV by aperture");
  std::vector<SunEstimate> out;
  out.reserve(images.size());
  for (std::size_t k = 0; k < images.size(); ++k) {
    const int q = subfov_classes[k];
    if (q < 0 || q > 3) throw std::invalid_argument("pattern estimator: quadrant hint " + std::to_string(q));
    out.push_back(estimateOne(images[k], quadrantWindow(q)));
  }
  return out;
}

std::vector<SunEstimate> PatternEstimator::estimateWithCoarseDirections(const std::vector<cv::Mat>& images,
                                                                        const CoarseDirections& coarse) {
  if (coarse.size() != images.size())
    throw std::invalid_argument("pattern estimator: " + std::to_string(coarse.size()) + " coarse directions for " +
                                std::to_string(images.size()) + " images");
  std::vector<SunEstimate> out;
  out.reserve(images.size());
  for (std::size_t k = 0; k < images.size(); ++k) out.push_back(estimateOne(images[k], {}, coarse[k]));
  return out;
}

SunEstimate PatternEstimator::estimateOne(const cv::Mat& image, const std::optional<AngleWindow>& window,
                                          const std::optional<CoarseDirection>& coarse) const {
  SunEstimate est;
  est.status = input_.badImageStatus(image);
  if (!est.status.empty()) return est;
  if (cv::countNonZero(image) == 0) {
    est.status = status::kNoSun;
    return est;
  }
  // Two places fit the template about equally: the design's whole image at
  // each (its vignetting, obliquity and exposure at that angle, which the
  // template at normal incidence leaves out) says which one the image is,
  // before the solve fits the chosen one on every pixel.
  bool ambiguous = false;
  std::optional<AliasEvidence> evidence;  // its unexplained_z is the answer's place's
  const auto choose = [&](const PatternSolution& best, const PatternSolution& runner_up) {
    ambiguous = runner_up.residual_rms_dn < kAmbiguousCostRatio * best.residual_rms_dn;
    evidence.reset();
    if (!ambiguous) return false;
    evidence = aliasEvidence(image, best.angles_rad, runner_up.angles_rad);
    // Otherwise a coarse direction that lies clearly nearer one place: at the
    // places the design's image cannot tell apart (mirror images of each
    // other, 1.15 % of thesis_ca's field) it is all there is.
    bool other_nearer = false, coarse_decides = false;
    if (!evidence->decides() && coarse) {
      const Eigen::Vector2d c(coarse->alpha_rad, coarse->beta_rad);
      const double here = (best.angles_rad - c).norm(), there = (runner_up.angles_rad - c).norm();
      coarse_decides = std::abs(there - here) >= kCoarseDecisionSigmas * coarse->sigma_rad;
      other_nearer = there < here;
    }
    if (!evidence->decides() && !coarse_decides) return false;  // ambiguous: the better fit's angles
    ambiguous = false;
    return evidence->decides() ? evidence->z < 0.0 : other_nearer;
  };
  const auto solution = solver_.solve(image, window ? *window : field_, choose);
  if (!solution) {
    est.status = status::kNoMatch;
    return est;
  }
  est.alpha_rad = solution->angles_rad.x();
  est.beta_rad = solution->angles_rad.y();
  // The answer's place's excess (its decision measured it, else one render).
  const double unexplained_z = evidence ? evidence->unexplained_z : unexplainedLightZ(image, solution->angles_rad);
  est.unexplained_light_z = unexplained_z;
  const Eigen::Matrix2d scale = Eigen::Vector2d(sigma_scale_[0], sigma_scale_[1]).asDiagonal();
  const Eigen::Matrix2d cov = scale * solution->covariance * scale * varianceInflation(unexplained_z);
  est.covariance = {cov(0, 0), cov(0, 1), cov(1, 0), cov(1, 1)};
  est.subfov_class = subFovClassOf(config_.subfov, geometry_, est.alpha_rad, est.beta_rad);
  if (ambiguous) {
    char figures[160];
    std::snprintf(figures, sizeof figures, " (likelihood ratio %.1f sigma, unexplained light chi^2 excess %.1f sigma)",
                  evidence->z, evidence->unexplained_z);
    est.status =
        status::withDetail(status::kAmbiguousAperture,
                           (evidence->unexplained_z > AliasEvidence::kMaxUnexplainedZ
                                ? "light the design does not hold leaves the choice open between here and alpha "
                                : "the pattern fits about equally here and at alpha ") +
                               std::to_string(radToDeg(solution->alternative_rad.x())) + ", beta " +
                               std::to_string(radToDeg(solution->alternative_rad.y())) + " deg" + figures);
    return est;
  }
  // Light the design does not hold (a ghost, stray light, debris) biases
  // the solve by more than its sigma says: on thesis_ca's ghost images an
  // excess above 5 held 27 % of the errors within 1 sigma; on nominal ones
  // it stayed below 3.
  if (unexplained_z > AliasEvidence::kMaxUnexplainedZ) {
    char figure[32];
    std::snprintf(figure, sizeof figure, "%.1f", unexplained_z);
    est.status =
        status::withDetail(status::kModelMismatch, std::string("light the design does not hold (chi^2 excess ") +
                                                       figure + " sigma) may bias the estimate");
    return est;
  }
  est.valid = cov.allFinite();
  if (!est.valid) est.status = status::kNotFinite;
  return est;
}

}  // namespace dss
