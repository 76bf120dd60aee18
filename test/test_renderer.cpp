// Whole-image rendering: determinism, symmetry, truth, anomalies, as-built errors
// (a unit's mask height in its spots' diffraction).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numeric>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <vector>

#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/common/row_runs.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/sim/dataset_generator.h"
#include "digital_sun_sensor/sim/field_coverage.h"
#include "digital_sun_sensor/sim/geometry.h"
#include "digital_sun_sensor/sim/readout.h"
#include "digital_sun_sensor/sim/renderer.h"

namespace dss {
namespace {

SensorConfig shipped(const std::string& name, const std::vector<std::string>& overrides = {}) {
  return loadSensorConfig(std::string(DSS_SOURCE_DIR) + "/config/sensors/" + name + ".yaml", overrides);
}

bool identical(const cv::Mat& a, const cv::Mat& b) {
  return a.size() == b.size() && a.type() == b.type() && cv::countNonZero(a != b) == 0;
}

// Centroid in a disk of `radius_px` about `centre_px` (detector-centred px):
// symmetric about the true centre, so the faint diffraction halo, which the
// detector edge would clip, cannot bias it.
Eigen::Vector2d windowedCentroidPx(const cv::Mat& electrons, const Eigen::Vector2d& centre_px, double radius_px) {
  double sx = 0, sy = 0, s = 0;
  for (int r = 0; r < electrons.rows; ++r) {
    for (int c = 0; c < electrons.cols; ++c) {
      const double x = c - 0.5 * (electrons.cols - 1), y = r - 0.5 * (electrons.rows - 1);
      if (std::hypot(x - centre_px.x(), y - centre_px.y()) > radius_px) continue;
      const double w = electrons.at<float>(r, c);
      sx += w * x;
      sy += w * y;
      s += w;
    }
  }
  return {sx / s, sy / s};
}

// The runs of a mask's row (sixteen bytes at a time where it can) against a
// byte-by-byte reading: any length, any non-zero byte value, runs that
// start, end or break anywhere within a word.
TEST(RowRuns, RunsAreThoseOfAByteByByteReading) {
  Rng rng(3);
  for (int trial = 0; trial < 2000; ++trial) {
    const int cols = static_cast<int>(rng.below(70));
    std::vector<std::uint8_t> row(static_cast<std::size_t>(cols));
    const double on = rng.uniform();  // from mostly dark to mostly lit rows
    for (auto& b : row) b = rng.uniform() < on ? static_cast<std::uint8_t>(1 + rng.below(255)) : 0;
    std::vector<std::pair<int, int>> expected, found;
    for (int c = 0; c < cols; ++c)
      if (row[static_cast<std::size_t>(c)] && (c == 0 || !row[static_cast<std::size_t>(c - 1)])) {
        int end = c;
        while (end < cols && row[static_cast<std::size_t>(end)]) ++end;
        expected.emplace_back(c, end);
      }
    forEachRun(row.data(), cols, [&](int begin, int end) { found.emplace_back(begin, end); });
    ASSERT_EQ(found, expected) << "trial " << trial << ", " << cols << " bytes";
  }
}

// A mask's edge runs against its erosion by a 3 x 3 square (off the mask
// counting as marked): masks from sparse to full, of one row or column too.
TEST(RowRuns, MaskEdgeIsThatOfAnErosion) {
  Rng rng(5);
  for (int trial = 0; trial < 400; ++trial) {
    const int rows = 1 + static_cast<int>(rng.below(12)), cols = 1 + static_cast<int>(rng.below(40));
    cv::Mat mask(rows, cols, CV_8U);
    const double on = rng.uniform();
    for (int r = 0; r < rows; ++r)
      for (int c = 0; c < cols; ++c) mask.at<std::uint8_t>(r, c) = rng.uniform() < on ? 255 : 0;
    cv::Mat inner;
    cv::erode(mask, inner, cv::Mat(), cv::Point(-1, -1), 1, cv::BORDER_CONSTANT, cv::Scalar(255));
    const cv::Mat expected = mask & ~inner;
    cv::Mat found = cv::Mat::zeros(rows, cols, CV_8U);
    int last_row = -1, last_end = -1;
    forEachEdgeRun(mask.ptr<std::uint8_t>(), rows, cols, mask.step[0], [&](int r, int begin, int end) {
      ASSERT_TRUE(r > last_row || (r == last_row && begin > last_end)) << "runs out of order or touching";
      ASSERT_LT(begin, end);
      found.rowRange(r, r + 1).colRange(begin, end).setTo(255);
      last_row = r, last_end = end;
    });
    ASSERT_EQ(cv::countNonZero(found != expected), 0) << "trial " << trial << ", " << rows << " x " << cols;
  }
}

TEST(Renderer, SameSeedSameImageAndThreadCountDoesNotMatter) {
  const SensorConfig c = shipped("thesis_sa");
  DatasetSpec spec;
  spec.count = 6;
  spec.seed = 42;
  spec.threads = 1;
  std::vector<cv::Mat> one, two, other;
  DatasetGenerator(c, spec).run([&](const DatasetItem& i) { one.push_back(i.image.clone()); });
  spec.threads = 2;
  DatasetGenerator(c, spec).run([&](const DatasetItem& i) { two.push_back(i.image.clone()); });
  spec.seed = 43;
  DatasetGenerator(c, spec).run([&](const DatasetItem& i) { other.push_back(i.image.clone()); });
  ASSERT_EQ(one.size(), 6u);
  for (std::size_t i = 0; i < one.size(); ++i) {
    EXPECT_TRUE(identical(one[i], two[i])) << i;
    EXPECT_FALSE(identical(one[i], other[i])) << i;
  }
}

TEST(Renderer, SpotCentroidAtTruthWithSunDisk) {
  // Noise-free image, vignetting off: the light's centroid is the true centre.
  const SensorConfig c = shipped("thesis_sa", {"optics.vignetting=false"});
  const Renderer r(SensorInstance::nominalOf(c));
  for (auto [a, b] : {std::pair{0.3, 0.2}, {-2.2, 1.9}, {1.7, -2.4}}) {
    ImageTruth t;
    const cv::Mat e = r.expectedElectrons(sunVectorFromAngles(a * kRadPerDeg, b * kRadPerDeg), &t);
    ASSERT_EQ(t.spots.size(), 1u);
    EXPECT_NEAR(t.spots[0].x_px, -5000.0 * std::tan(a * kRadPerDeg) / 1.55, 1e-6);
    EXPECT_NEAR(t.spots[0].y_px, -5000.0 * std::tan(b * kRadPerDeg) / 1.55, 1e-6);
    const Eigen::Vector2d c_px = windowedCentroidPx(e, {t.spots[0].x_px, t.spots[0].y_px}, 100.0);
    EXPECT_NEAR(c_px.x(), t.spots[0].x_px, 0.02) << a << "," << b;
    EXPECT_NEAR(c_px.y(), t.spots[0].y_px, 0.02) << a << "," << b;
    EXPECT_EQ(t.subfov_class, quadrantClass(a * kRadPerDeg, b * kRadPerDeg));
  }
}

TEST(Renderer, QuarterTurnOfTheSunRotatesTheImage) {
  const SensorConfig c = shipped("thesis_sa");
  const Renderer r(SensorInstance::nominalOf(c));
  const Eigen::Vector3d s = sunVectorFromAngles(2.0 * kRadPerDeg, 1.0 * kRadPerDeg);
  const Eigen::Vector3d rotated(-s.y(), s.x(), s.z());  // 90 deg about +z
  const cv::Mat a = r.expectedElectrons(s, nullptr), b = r.expectedElectrons(rotated, nullptr);
  // (x, y) -> (-y, x): pixel (row r, col c) -> (row c, col W-1-r).
  double peak, worst = 0.0;
  cv::minMaxLoc(a, nullptr, &peak);
  for (int row = 0; row < a.rows; ++row) {
    for (int col = 0; col < a.cols; ++col) {
      worst =
          std::max(worst, static_cast<double>(std::abs(a.at<float>(row, col) - b.at<float>(col, a.cols - 1 - row))));
    }
  }
  EXPECT_LT(worst / peak, 1e-3);
}

TEST(Renderer, AsBuiltOffsetMovesTheSpot) {
  const SensorConfig c = shipped("thesis_sa", {"as_built.offset_sigma_um=20"});
  const SensorInstance built = SensorInstance::draw(c, 17);
  ASSERT_GT(built.mask_offset_um.head<2>().norm(), 1.0);
  ImageTruth t;
  Renderer(built).expectedElectrons(Eigen::Vector3d::UnitZ(), &t);
  EXPECT_NEAR(t.spots[0].x_px * 1.55, built.mask_offset_um.x(), 1e-6);
  EXPECT_NEAR(t.spots[0].y_px * 1.55, built.mask_offset_um.y(), 1e-6);
}

TEST(Renderer, AsBuiltHeightChangesTheSpotsDiffraction) {
  // A unit whose mask sits 20 um higher above its glass window (an air gap)
  // is the design with its mask 20 um higher: the same light, diffraction
  // included, not the design's spots moved; and a lower mask rests on a
  // thinner window.
  const Eigen::Vector3d sun = sunVectorFromAngles(50 * kRadPerDeg, 20 * kRadPerDeg);
  for (const double change_um : {20.0, -20.0}) {
    const SensorConfig design = shipped("wide_ma");
    SensorInstance unit = SensorInstance::nominalOf(design);
    unit.nominal = false;
    unit.mask_offset_um.z() = change_um;
    std::vector<std::string> moved = {"mask.height_mm=" + std::to_string(0.5 + change_um / 1000.0)};
    if (change_um < 0) moved.push_back("cover_glass.thickness_mm=" + std::to_string(0.5 + change_um / 1000.0));
    const cv::Mat built = Renderer(unit).expectedElectrons(sun, nullptr);
    const cv::Mat drawn =
        Renderer(SensorInstance::nominalOf(shipped("wide_ma", moved))).expectedElectrons(sun, nullptr);
    EXPECT_LT(cv::norm(built, drawn, cv::NORM_INF), 1e-3 * cv::norm(drawn, cv::NORM_INF)) << change_um << " um";
    const cv::Mat nominal = Renderer(SensorInstance::nominalOf(design)).expectedElectrons(sun, nullptr);
    EXPECT_GT(cv::norm(nominal, drawn, cv::NORM_INF), 0.05 * cv::norm(drawn, cv::NORM_INF)) << change_um << " um";
  }
}

TEST(Renderer, AnomaliesShowUp) {
  // Hot pixels: bright at their fixed sites.
  const SensorConfig hot = shipped("thesis_sa", {"anomalies.hot_pixels.count=20", "threshold.enabled=false"});
  const SensorInstance with_hot = SensorInstance::draw(hot, 3);
  const cv::Mat img = Renderer(with_hot).render(sunVectorFromAngles(1 * kRadPerDeg, 1 * kRadPerDeg), 5, nullptr);
  int bright = 0;
  for (const auto& hp : with_hot.hot_pixels) bright += img.ptr<std::uint8_t>()[hp.index] > 2 ? 1 : 0;
  EXPECT_GE(bright, 15);
  // Stray light raises the background everywhere.
  const SensorConfig stray = shipped("thesis_sa", {"anomalies.stray_light.probability=1", "threshold.enabled=false"});
  const Renderer sr(SensorInstance::nominalOf(stray));
  Rng rng(4);
  ImageTruth t;
  const cv::Mat e = sr.expectedElectrons(Eigen::Vector3d::UnitZ(), &t, &rng);
  EXPECT_TRUE(t.stray_light);
  EXPECT_GT(e.at<float>(0, 0), 0.0f);
  // Debris blocks part of an aperture: less light gets through.
  const SensorConfig debris = shipped("thesis_sa", {"anomalies.debris.probability=1"});
  const SensorInstance dirty = SensorInstance::draw(debris, 8);
  ASSERT_EQ(dirty.apertures[0].occluders.size(), 1u);
  ImageTruth clean_t, dirty_t;
  Renderer(SensorInstance::nominalOf(debris)).expectedElectrons(Eigen::Vector3d::UnitZ(), &clean_t);
  Renderer(dirty).expectedElectrons(Eigen::Vector3d::UnitZ(), &dirty_t);
  EXPECT_LT(dirty_t.spots[0].relative_flux, 0.99f * clean_t.spots[0].relative_flux);
}

TEST(Renderer, LightsOnlyTheMarkedPixels) {
  // What the pattern estimator's design images rely on: marked pixels read
  // as in the whole render when the image's lit pixels are all marked;
  // unmarked ones read as unlit.
  const SensorConfig c = shipped("thesis_ma");
  const Renderer r(SensorInstance::nominalOf(c));
  RenderOptions options;
  options.noise = false;
  options.anomalies = false;
  const Eigen::Vector3d sun = sunVectorFromAngles(1.3 * kRadPerDeg, -0.7 * kRadPerDeg);
  const cv::Mat whole = r.render(sun, 1, nullptr, options);
  ASSERT_GT(cv::countNonZero(whole), 100);
  cv::Mat marked;
  cv::dilate(whole > 0, marked, cv::Mat::ones(3, 3, CV_8U));
  options.only = &marked;
  EXPECT_TRUE(identical(r.render(sun, 1, nullptr, options), whole));
  // Unmark the lit pixels of the detector's left half but its brightest.
  cv::Point brightest;
  cv::minMaxLoc(whole, nullptr, nullptr, nullptr, &brightest);
  const int half = brightest.x < whole.cols / 2 ? whole.cols / 2 : 0;  // the half without it
  cv::Mat partly = marked.clone();
  partly(cv::Rect(half, 0, whole.cols / 2, whole.rows)).setTo(0);
  options.only = &partly;
  const cv::Mat some = r.render(sun, 1, nullptr, options);
  cv::Mat expected = whole.clone();
  expected(cv::Rect(half, 0, whole.cols / 2, whole.rows)).setTo(0);
  ASSERT_GT(cv::countNonZero(whole) - cv::countNonZero(expected), 0) << "the unmarked half holds light";
  EXPECT_TRUE(identical(some, expected));
  const cv::Mat wrong_size = cv::Mat::ones(8, 8, CV_8U);
  options.only = &wrong_size;
  EXPECT_THROW(r.render(sun, 1, nullptr, options), std::invalid_argument);
}

TEST(Renderer, SpotsWholePixelsApartEqualTheirOwnSplats) {
  // thesis_ma's apertures (and their ghosts) lie whole pixels apart: the
  // render resamples their spot once and adds it at pixel offsets. Each
  // aperture rendered alone (its own bilinear splat) sums to the same image.
  SensorConfig c = shipped("thesis_ma");
  c.exposure.mode = ExposureMode::kFixed;
  c.anomalies.ghost_probability = 1.0;
  c.anomalies.stray_light_probability = 0.0;
  const Eigen::Vector3d sun = sunVectorFromAngles(1.3 * kRadPerDeg, -0.7 * kRadPerDeg);
  Rng rng(3);
  const Renderer all(SensorInstance::nominalOf(c));  // holds the shared spot cache for the others
  const cv::Mat whole = all.expectedElectrons(sun, nullptr, &rng);
  cv::Mat sum = cv::Mat::zeros(whole.size(), CV_32F);
  for (const auto& aperture : shipped("thesis_ma").mask.apertures) {
    SensorConfig alone = c;
    alone.mask.apertures = {aperture};
    Rng same(3);
    sum += Renderer(SensorInstance::nominalOf(alone)).expectedElectrons(sun, nullptr, &same);
  }
  double peak = 0.0;
  cv::minMaxLoc(whole, nullptr, &peak);
  ASSERT_GT(peak, 0.0);
  // Float rounding: one aperture alone blends its maps per pixel, several compose them first.
  EXPECT_LT(cv::norm(whole, sum, cv::NORM_INF), 1e-5 * peak);
}

TEST(Renderer, WideFieldSpotsLeaveTheDetectorAndClassIsNearestAperture) {
  const SensorConfig c = shipped("wide_ma");
  const Renderer r(SensorInstance::nominalOf(c));
  ImageTruth t;
  r.expectedElectrons(Eigen::Vector3d::UnitZ(), &t);
  EXPECT_EQ(t.subfov_class, 24);  // centre of the 7 x 7 grid
  ImageTruth tilted;
  r.expectedElectrons(sunVectorFromAngles(50 * kRadPerDeg, -35 * kRadPerDeg), &tilted);
  int on = 0;
  for (const auto& s : tilted.spots) on += s.on_detector ? 1 : 0;
  EXPECT_GT(on, 2);
  EXPECT_LT(on, 49);
  EXPECT_NE(tilted.subfov_class, 24);
}

TEST(Sampling, GridFollowsPublishedProtocol) {
  const SensorConfig c = shipped("thesis_sa");
  const AttitudeSampler grid(c, SamplingMode::kGrid, 1);
  EXPECT_EQ(grid.gridPoints(), 513u * 513u);
  // Every grid attitude puts the spot on an integer pixel offset.
  const Renderer r(SensorInstance::nominalOf(c));
  for (std::uint64_t i = 0; i < 20; ++i) {
    ImageTruth t;
    const Eigen::Vector3d s = grid.sunVector(i);
    const auto hit = traceToDetector(Eigen::Vector3d(0, 0, 5000.0), s, {});
    ASSERT_TRUE(hit);
    EXPECT_NEAR(hit->x() / 1.55, std::round(hit->x() / 1.55), 1e-6);
    EXPECT_NEAR(hit->y() / 1.55, std::round(hit->y() / 1.55), 1e-6);
  }
}

TEST(Sampling, EdgeSamplingStaysInTheOuterBand) {
  const SensorConfig c = shipped("thesis_sa");  // +-4.54 deg
  const double band_deg = 0.2, limit_rad = (4.54 - band_deg) * kRadPerDeg;
  const AttitudeSampler edge(c, SamplingMode::kEdge, 7, band_deg);
  int corner = 0, sides[4] = {0, 0, 0, 0};
  for (std::uint64_t i = 0; i < 2000; ++i) {
    const SunAnglesRad a = anglesFromSunVector(edge.sunVector(i));
    const bool alpha_edge = std::abs(a.alpha) >= limit_rad - 1e-12, beta_edge = std::abs(a.beta) >= limit_rad - 1e-12;
    ASSERT_TRUE(alpha_edge || beta_edge) << "sample " << i << " inside the band's inner border";
    ASSERT_LE(std::abs(a.alpha), 4.54 * kRadPerDeg + 1e-12);
    ASSERT_LE(std::abs(a.beta), 4.54 * kRadPerDeg + 1e-12);
    corner += alpha_edge && beta_edge ? 1 : 0;
    if (alpha_edge) ++sides[a.alpha > 0 ? 0 : 1];
    if (beta_edge) ++sides[a.beta > 0 ? 2 : 3];
  }
  // Uniform over the band (area 4 (2 a w - w^2), a = 4.54, w = 0.2): each side
  // holds 2 a w of it (25.6 %, corners counted on both of theirs), the four
  // corners 4 w^2 (2.3 %).
  for (int side : sides) EXPECT_NEAR(side, 511, 60);
  EXPECT_NEAR(corner, 45, 20);
  // Deterministic per index, and a band outside (0, half field] is refused.
  EXPECT_EQ(edge.sunVector(5), AttitudeSampler(c, SamplingMode::kEdge, 7, band_deg).sunVector(5));
  EXPECT_THROW(AttitudeSampler(c, SamplingMode::kEdge, 7, 0.0), std::invalid_argument);
  EXPECT_THROW(AttitudeSampler(c, SamplingMode::kEdge, 7, 5.0), std::invalid_argument);
  EXPECT_EQ(parseSamplingMode("edge"), SamplingMode::kEdge);
  EXPECT_EQ(toString(SamplingMode::kEdge), "edge");
}

// A lab plan's first N points cover the field evenly for every N: 25 leave
// no ninth of it empty and 50 no 25th (uniform random draws leave a ninth
// empty about half the time), for every seed; each seed another plan.
TEST(Sampling, SpreadPlanCoversTheFieldForEveryCount) {
  const SensorConfig c = shipped("wide_ma");  // +-60 deg
  const double alpha_max = c.fov.alpha_max_deg * kRadPerDeg, beta_max = c.fov.beta_max_deg * kRadPerDeg;
  auto emptiest = [&](const AttitudeSampler& sampler, int count, int cells_per_side) {
    std::vector<double> alpha, beta;
    for (int i = 0; i < count; ++i) {
      const SunAnglesRad a = anglesFromSunVector(sampler.sunVector(i));
      EXPECT_LE(std::abs(a.alpha), alpha_max + 1e-12);
      EXPECT_LE(std::abs(a.beta), beta_max + 1e-12);
      alpha.push_back(a.alpha);
      beta.push_back(a.beta);
    }
    const FieldCoverage coverage = measureFieldCoverage(c, alpha, beta, cells_per_side);
    EXPECT_EQ(std::accumulate(coverage.counts.begin(), coverage.counts.end(), 0), count);
    return coverage.leastCount();
  };
  int random_with_an_empty_ninth = 0;
  for (std::uint64_t seed = 1; seed <= 20; ++seed) {
    const AttitudeSampler plan(c, SamplingMode::kSpread, seed);
    EXPECT_GE(emptiest(plan, 25, 3), 1) << seed;
    EXPECT_GE(emptiest(plan, 50, 5), 1) << seed;
    random_with_an_empty_ninth += emptiest(AttitudeSampler(c, SamplingMode::kRandom, seed), 25, 3) == 0 ? 1 : 0;
  }
  EXPECT_GE(random_with_an_empty_ninth, 3);
  EXPECT_NE(AttitudeSampler(c, SamplingMode::kSpread, 1).sunVector(0),
            AttitudeSampler(c, SamplingMode::kSpread, 2).sunVector(0));
  EXPECT_EQ(AttitudeSampler(c, SamplingMode::kSpread, 1).sunVector(7),
            AttitudeSampler(c, SamplingMode::kSpread, 1).sunVector(7));
  // Directions outside the field are not counted; a partition needs a cell.
  EXPECT_EQ(measureFieldCoverage(c, {0.0, 1.2 * alpha_max}, {0.0, 0.0}, 1).counts, std::vector<int>{1});
  EXPECT_THROW(measureFieldCoverage(c, {0.0}, {0.0}, 0), std::invalid_argument);
  EXPECT_THROW(measureFieldCoverage(c, {0.0}, {}, 3), std::invalid_argument);
  EXPECT_EQ(parseSamplingMode("spread"), SamplingMode::kSpread);
  EXPECT_EQ(toString(SamplingMode::kSpread), "spread");
}

// The noise-free readout gives the detector's own codes (what the pattern
// estimator's design canvases convert their light with), through thesis_ca's
// rescaling threshold and without a threshold: every electron count of a
// ramp past the full well, and the unlit code below unlitBelowE.
TEST(NoiseFreeReadout, GivesTheDetectorsNoiseFreeCodes) {
  for (const char* name : {"thesis_ca", "thesis_sa"}) {
    const SensorConfig config = shipped(name);
    const Renderer renderer(SensorInstance::nominalOf(config));
    const NoiseFreeReadout readout(config, true);
    const int n = 4000;
    cv::Mat electrons(1, n, CV_32F);
    for (int i = 0; i < n; ++i) electrons.at<float>(0, i) = static_cast<float>(1.2 * config.noise.full_well_e * i / n);
    RenderOptions options;
    options.noise = false;
    Rng unused(1);
    cv::Mat codes;
    renderer.detect(electrons, 1e-3, unused, options).convertTo(codes, CV_32S);
    const double below = readout.unlitBelowE(0.0);
    int unlit = 0;
    for (int i = 0; i < n; ++i) {
      const float e = electrons.at<float>(0, i);
      const int expected =
          e < below ? readout.unlitCode(0.0) : readout.code(std::min<double>(e, config.noise.full_well_e));
      ASSERT_EQ(codes.at<int>(0, i), expected) << name << " at " << e << " e";
      unlit += codes.at<int>(0, i) == readout.unlitCode(0.0);
    }
    EXPECT_GT(unlit, 0) << name;
    EXPECT_EQ(readout.code(1.5 * config.noise.full_well_e), config.maxCode()) << name;  // clipped by the ADC
    // The vectorised run: code() of each, the unlit code below unlitBelowE among them.
    std::vector<std::uint16_t> run(n);
    readout.codes(electrons.ptr<float>(), 1.0f, config.noise.full_well_e, n, run.data());
    for (int i = 0; i < n; ++i)
      ASSERT_EQ(run[i], codes.at<int>(0, i)) << name << " at " << electrons.at<float>(0, i) << " e";
  }
}

}  // namespace
}  // namespace dss
