// The whole-pattern solve of a mask whose spots merge (thesis_ca): it finds
// the pattern's shift without a start, reads noise-free images to the
// template's fidelity, and says when the pattern fits two places in the
// field (thesis_ca's three column groups are translates of one another,
// 5.74 deg apart in alpha), which the design's rendered image at each, or
// a quadrant hint, decides; light the design lacks (a ghost) leaves it open.
// Its design's diffraction cache can be computed before the first image.
#include <gtest/gtest.h>

#include <cmath>
#include <utility>

#include "digital_sun_sensor/baseline/design_canvases.h"
#include "digital_sun_sensor/baseline/pattern_estimator.h"
#include "digital_sun_sensor/baseline/pattern_solve.h"
#include "digital_sun_sensor/common/estimate_status.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/sim/geometry.h"
#include "digital_sun_sensor/sim/renderer.h"
#include "digital_sun_sensor/sim/spot_cache.h"

namespace dss {
namespace {

std::string shippedPath(const std::string& name) {
  return std::string(DSS_SOURCE_DIR) + "/config/sensors/" + name + ".yaml";
}

cv::Mat noiseFree(const Renderer& renderer, double alpha_deg, double beta_deg) {
  RenderOptions options;
  options.noise = false;
  return renderer.render(sunVectorFromAngles(degToRad(alpha_deg), degToRad(beta_deg)), 1, nullptr, options);
}

const PatternEstimatorOptions kNoSigmaImages{0, 1};

class PatternSolveTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    config_ = new SensorConfig(loadSensorConfig(shippedPath("thesis_ca")));
    solver_ = new PatternSolver(*config_);
    renderer_ = new Renderer(SensorInstance::nominalOf(*config_));
  }
  static void TearDownTestSuite() {
    delete renderer_;
    delete solver_;
    delete config_;
  }
  // A drawn unit of the design (its pixels' gain and dark spread) at `truth`,
  // without and with a ghost, the same noise seed.
  static std::pair<cv::Mat, cv::Mat> withAndWithoutGhost(const Eigen::Vector2d& truth, std::uint64_t seed) {
    SensorConfig ghostly = *config_;
    ghostly.anomalies.ghost_probability = 1.0;
    const Renderer without_ghost(SensorInstance::draw(*config_, 7)), with_ghost(SensorInstance::draw(ghostly, 7));
    const Eigen::Vector3d sun = sunVectorFromAngles(truth.x(), truth.y());
    return {without_ghost.render(sun, seed, nullptr), with_ghost.render(sun, seed, nullptr)};
  }
  static SensorConfig* config_;
  static PatternSolver* solver_;
  static Renderer* renderer_;
};
SensorConfig* PatternSolveTest::config_ = nullptr;
PatternSolver* PatternSolveTest::solver_ = nullptr;
Renderer* PatternSolveTest::renderer_ = nullptr;

// The template as the detector sees it at a shift: at zero shift each pixel
// reads the rendered value under it, a whole pixel's shift moves it by one
// pixel, and the gradient is the interpolant's own (finite differences of
// the shift).
TEST_F(PatternSolveTest, ShiftedTemplateReadsTheRenderAndItsGradient) {
  const PatternTemplate& pattern = solver_->patternTemplate();
  const int w = config_->detector.width_px, h = config_->detector.height_px;
  const double pitch = config_->detector.pitch_um;
  const int margin = (pattern.sidePx() - w) / 2;
  const auto at = [&](double shift_x_um, double shift_y_um, int col, int row, double* gx = nullptr,
                      double* gy = nullptr) {
    double grad_x, grad_y;
    const double value = pattern.shifted(w, h, shift_x_um, shift_y_um).at(col, row, grad_x, grad_y);
    if (gx) *gx = grad_x;
    if (gy) *gy = grad_y;
    return value;
  };
  int steep = 0;
  for (int row = 0; row < h; row += 37)
    for (int col = 0; col < w; col += 41) {
      EXPECT_EQ(at(0.0, 0.0, col, row), pattern.values().at<double>(row + margin, col + margin));
      EXPECT_NEAR(at(pitch, -2.0 * pitch, col, row), at(0.0, 0.0, col - 1, row + 2), 1e-12);
      double gx, gy;
      const double shift_x = 0.37, shift_y = -0.81, step = 1e-4;
      at(shift_x, shift_y, col, row, &gx, &gy);
      // The pattern moves with the shift: d value / d shift = -gradient.
      const double dx = (at(shift_x + step, shift_y, col, row) - at(shift_x - step, shift_y, col, row)) / (2 * step);
      const double dy = (at(shift_x, shift_y + step, col, row) - at(shift_x, shift_y - step, col, row)) / (2 * step);
      EXPECT_NEAR(-dx, gx, 1e-6 + 1e-6 * std::abs(gx));
      EXPECT_NEAR(-dy, gy, 1e-6 + 1e-6 * std::abs(gy));
      if (std::abs(gx) > 1e-3) ++steep;
    }
  EXPECT_GT(steep, 10);  // the pattern has edges where the pixels were read
  double gx, gy;
  EXPECT_EQ(at(0.0, 0.0, -margin - 5, 0, &gx, &gy), 0.0);  // outside the rendered area
  EXPECT_EQ(gx, 0.0);
}

// The fit on every pixel reads the template along row runs: the same values
// and gradients as pixel by pixel, to the bit, also where a run leaves the
// rendered area.
TEST_F(PatternSolveTest, ShiftedTemplateReadAlongARunEqualsPixelByPixel) {
  const PatternTemplate& pattern = solver_->patternTemplate();
  const int w = config_->detector.width_px, h = config_->detector.height_px;
  const int margin = (pattern.sidePx() - w) / 2;
  const PatternTemplate::Shifted shifted = pattern.shifted(w, h, 3.71, -2.29);
  const int count = 40;
  std::vector<double> value(count), gx(count), gy(count), value_only(count);
  // Inside; across the left edge of the rendered area; along its last rows.
  for (const auto& [col, row] :
       std::vector<std::pair<int, int>>{{100, 200}, {-margin - 20, 50}, {300, h + margin - 2}}) {
    shifted.run(col, row, count, value.data(), gx.data(), gy.data());
    shifted.run(col, row, count, value_only.data());
    int lit = 0;
    for (int i = 0; i < count; ++i) {
      double expected_gx, expected_gy;
      const double expected = shifted.at(col + i, row, expected_gx, expected_gy);
      EXPECT_EQ(value[i], expected) << col + i << ", " << row;
      EXPECT_EQ(value_only[i], expected);
      EXPECT_EQ(gx[i], expected_gx);
      EXPECT_EQ(gy[i], expected_gy);
      lit += expected > 0.0;
    }
    if (row == 200) {
      EXPECT_GT(lit, 0) << "the run reads some of the pattern";
    }
  }
}

// Where the shifted template reaches a share of its brightest value on the
// detector: the same pixels as a brute-force reading of the whole window,
// for windows whose brightest pixel lies at each of their edges (the peak
// is taken from block maxima and the edge strips beside them), windows cut
// by the template's edge, and a plain shift.
TEST_F(PatternSolveTest, ReachingTakesTheWindowsBrightestPixel) {
  const PatternTemplate& pattern = solver_->patternTemplate();
  const cv::Mat& values = pattern.values();
  const int w = config_->detector.width_px, h = config_->detector.height_px, side = pattern.sidePx();
  const double centre = 0.5 * (side - 1);
  cv::Point brightest;
  cv::minMaxLoc(values, nullptr, nullptr, nullptr, &brightest);
  // The shift [um] that puts the window's first pixel on template pixel (u0, v0).
  auto shiftTo = [&](int u0, int v0) {
    return Eigen::Vector2d((centre - 0.5 * (w - 1) - u0) * pattern.pitchUm(),
                           (centre - 0.5 * (h - 1) - v0) * pattern.pitchUm());
  };
  std::vector<std::pair<int, int>> origins{{(side - w) / 2, (side - h) / 2}, {-100, 40}, {side - w + 77, side - 30}};
  for (int d : {0, 5, 11, 15}) {
    origins.emplace_back(brightest.x - d, brightest.y - d);                      // the peak near the top left
    origins.emplace_back(brightest.x - (w - 1) + d, brightest.y - (h - 1) + d);  // near the bottom right
  }
  for (const auto& [u0, v0] : origins) {
    const Eigen::Vector2d shift = shiftTo(u0, v0);
    const cv::Rect inside = cv::Rect(u0, v0, w, h) & cv::Rect(0, 0, side, side);
    ASSERT_GT(inside.area(), 0);
    double peak = 0.0;
    cv::minMaxLoc(values(inside), nullptr, &peak);
    cv::Mat expected = cv::Mat::zeros(h, w, CV_8U);
    cv::Mat(values(inside) >= 0.5 * peak).copyTo(expected(inside - cv::Point(u0, v0)));
    const cv::Mat got = pattern.reaching(w, h, shift.x(), shift.y(), 0.5);
    EXPECT_EQ(cv::countNonZero(got != expected), 0) << "window from template pixel " << u0 << ", " << v0;
    EXPECT_GT(cv::countNonZero(got), 0);
  }
}

// The image at normal incidence is the template, quantised to 8 bits and
// cut by the threshold: read to 0.00005 deg (0.004 um at the mask height).
TEST_F(PatternSolveTest, NormalIncidenceIsTheTemplateItself) {
  const auto s = solver_->solve(noiseFree(*renderer_, 0.0, 0.0));
  ASSERT_TRUE(s);
  EXPECT_LT(std::abs(radToDeg(s->angles_rad.x())), 5e-5);
  EXPECT_LT(std::abs(radToDeg(s->angles_rad.y())), 5e-5);
}

// Without a start: the search finds the shift, Gauss-Newton reads it to
// the template's fidelity (the spots' shape changes with the angle through
// vignetting: up to 0.0006 deg, 0.05 um at the mask height, near 4 deg).
// Where |alpha| < 0.9 deg no other shift in the field fits: answered.
TEST_F(PatternSolveTest, FindsTheShiftOfNoiseFreeImages) {
  const PatternEstimator estimator(*config_, kNoSigmaImages);
  for (const auto& angles : {Eigen::Vector2d(0.7, -3.9), Eigen::Vector2d(-0.4, 2.2), Eigen::Vector2d(0.9, 4.4)}) {
    const SunEstimate e = estimator.estimateOne(noiseFree(*renderer_, angles.x(), angles.y()));
    ASSERT_TRUE(e.valid) << e.status;
    EXPECT_NEAR(radToDeg(e.alpha_rad), angles.x(), 1e-3) << angles.transpose();
    EXPECT_NEAR(radToDeg(e.beta_rad), angles.y(), 1e-3) << angles.transpose();
  }
}

// At alpha = -3 deg the middle column group sits where the left one would
// at +2.74 deg: the template fits both about equally. The design's image
// rendered at each (its vignetting and exposure there) tells them apart,
// here by many noise deviations; a quadrant hint needs no such look.
TEST_F(PatternSolveTest, RepeatingPatternIsDecidedByTheDesignsImageOrTheQuadrant) {
  const cv::Mat image = noiseFree(*renderer_, -3.0, 1.0);
  const auto s = solver_->solve(image);
  ASSERT_TRUE(s);
  EXPECT_LT(s->alternative_cost_ratio, PatternEstimator::kAmbiguousCostRatio);
  const double period_deg = std::abs(radToDeg(s->angles_rad.x() - s->alternative_rad.x()));
  EXPECT_NEAR(period_deg, 5.74, 0.05);
  // A caller that takes the runner-up gets the fit there, the best
  // candidate as its alternative; one that keeps the best, the same
  // solution as without a choice.
  int asked = 0;
  const auto other =
      solver_->solve(image, std::nullopt, [&](const PatternSolution& best, const PatternSolution& runner_up) {
        ++asked;
        EXPECT_GT((best.angles_rad - runner_up.angles_rad).norm(), degToRad(PatternSolution::kDistinctDeg));
        return true;
      });
  ASSERT_TRUE(other);
  EXPECT_EQ(asked, 1);
  EXPECT_NEAR(radToDeg(other->angles_rad.x()), radToDeg(s->alternative_rad.x()), 0.01);
  EXPECT_NEAR(radToDeg(other->alternative_rad.x()), radToDeg(s->angles_rad.x()), 0.01);
  EXPECT_LT(other->residual_rms_dn, 1.1 * s->residual_rms_dn);
  const auto kept =
      solver_->solve(image, std::nullopt, [](const PatternSolution&, const PatternSolution&) { return false; });
  ASSERT_TRUE(kept);
  EXPECT_EQ(kept->angles_rad, s->angles_rad);
  EXPECT_EQ(kept->alternative_rad, s->alternative_rad);

  PatternEstimator estimator(*config_, kNoSigmaImages);
  EXPECT_EQ(estimator.source(), "pattern");
  const Eigen::Vector2d truth(degToRad(-3.0), degToRad(1.0));
  const Eigen::Vector2d alias = std::abs(s->angles_rad.x() - truth.x()) < 0.01 ? s->alternative_rad : s->angles_rad;
  const AliasEvidence evidence = estimator.aliasEvidence(image, truth, alias);
  EXPECT_GT(evidence.z, AliasEvidence::kMinZ);
  EXPECT_TRUE(evidence.decides());
  // Seen from the alias, the same evidence with its sign turned.
  EXPECT_NEAR(estimator.aliasEvidence(image, alias, truth).z, -evidence.z, 1e-9 * std::abs(evidence.z));
  const SunEstimate plain = estimator.estimate({image}).at(0);
  ASSERT_TRUE(plain.valid) << plain.status;
  EXPECT_NEAR(radToDeg(plain.alpha_rad), -3.0, 1e-3);
  EXPECT_NEAR(radToDeg(plain.beta_rad), 1.0, 1e-3);
  const SunEstimate hinted = estimator.estimateWithSubFovHints({image}, {quadrantClass(truth.x(), truth.y())}).at(0);
  ASSERT_TRUE(hinted.valid) << hinted.status;
  EXPECT_NEAR(radToDeg(hinted.alpha_rad), -3.0, 1e-3);
  EXPECT_NEAR(radToDeg(hinted.beta_rad), 1.0, 1e-3);
  EXPECT_EQ(hinted.subfov_class, quadrantClass(truth.x(), truth.y()));
  EXPECT_GT(hinted.covariance[0], 0.0);
}

// A ghost (the pattern again, 2 % as bright, one more round trip of the
// drift away) can tip the choice between two places by tens of noise
// deviations. The decision holds only where the image is otherwise what the
// design explains: with the ghost, the chi^2 excess declines it; the same
// image without the ghost (same noise seed) is decided.
TEST_F(PatternSolveTest, AliasChoiceIsDeclinedWhereLightTheDesignLacksCouldTipIt) {
  const PatternEstimator estimator(*config_, kNoSigmaImages);
  const Eigen::Vector2d truth(degToRad(-3.0), degToRad(1.0));
  const auto [clean, ghosted] = withAndWithoutGhost(truth, 5);
  ASSERT_GT(cv::norm(clean, ghosted, cv::NORM_L1), 0.0);
  const auto s = solver_->solve(ghosted);
  ASSERT_TRUE(s);
  ASSERT_LT(s->alternative_cost_ratio, PatternEstimator::kAmbiguousCostRatio);
  const Eigen::Vector2d alias = std::abs(s->angles_rad.x() - truth.x()) < 0.01 ? s->alternative_rad : s->angles_rad;

  const AliasEvidence noisy = estimator.aliasEvidence(clean, truth, alias);
  EXPECT_TRUE(noisy.decides()) << noisy.z << " " << noisy.unexplained_z;
  EXPECT_LT(std::abs(noisy.unexplained_z), 4.0);
  const AliasEvidence ghost = estimator.aliasEvidence(ghosted, truth, alias);
  EXPECT_GT(ghost.unexplained_z, AliasEvidence::kMaxUnexplainedZ);
  EXPECT_FALSE(ghost.decides());
  const SunEstimate e = estimator.estimateOne(ghosted);
  EXPECT_FALSE(e.valid);
  EXPECT_EQ(status::statusCode(e.status), status::kAmbiguousAperture);
  EXPECT_NE(e.status.find("light the design does not hold"), std::string::npos) << e.status;
  EXPECT_TRUE(estimator.estimateOne(clean).valid);
}

// The design's images from its canvases (one wide render per node of the
// diffraction cache, read at the image's shift and blended in angle) are the
// rendered ones but for the last ADC step of a few pixels; a decision and an
// excess from them lie within a fraction of the margins that let them stand
// for rendered ones, and the answers are the same.
TEST_F(PatternSolveTest, DesignCanvasesStandInForRenderedDesignImages) {
  const DesignCanvases canvases(*renderer_, PatternEstimator::kFieldMarginDeg);
  // One ADC code through the threshold's rescaling, in delivered codes.
  const double code_step =
      std::ceil(config_->maxCode() / ((1.0 - config_->threshold.level_fraction) * config_->maxCode()));
  for (const auto& angles : {Eigen::Vector2d(-3.0, 1.0), Eigen::Vector2d(0.02, 2.0), Eigen::Vector2d(3.6, -4.3)}) {
    cv::Mat rendered;
    noiseFree(*renderer_, angles.x(), angles.y()).convertTo(rendered, CV_16U);
    const auto from_canvases = canvases.image(Eigen::Vector2d(degToRad(angles.x()), degToRad(angles.y())), nullptr);
    ASSERT_TRUE(from_canvases);
    cv::Mat differ, difference;
    cv::absdiff(rendered, *from_canvases, difference);
    double largest = 0.0;
    cv::minMaxLoc(difference, nullptr, &largest);
    EXPECT_LE(largest, code_step) << angles.transpose();
    EXPECT_LT(cv::countNonZero(difference), 0.02 * cv::countNonZero(rendered)) << angles.transpose();
  }
  EXPECT_FALSE(canvases.image(Eigen::Vector2d(degToRad(10.0), 0.0), nullptr));  // beyond the field

  PatternEstimatorOptions rendered_only = kNoSigmaImages;
  rendered_only.design_canvases = false;
  const PatternEstimator with(*config_, kNoSigmaImages), without(*config_, rendered_only);
  const Renderer unit(SensorInstance::draw(*config_, 7));
  for (const auto& angles : {Eigen::Vector2d(-3.0, 1.0), Eigen::Vector2d(2.1, -2.6), Eigen::Vector2d(-1.4, 3.3)}) {
    const Eigen::Vector2d truth(degToRad(angles.x()), degToRad(angles.y()));
    const cv::Mat image = unit.render(sunVectorFromAngles(truth.x(), truth.y()), 3, nullptr);
    const auto s = solver_->solve(image);
    ASSERT_TRUE(s);
    ASSERT_LT(s->alternative_cost_ratio, PatternEstimator::kAmbiguousCostRatio) << angles.transpose();
    const Eigen::Vector2d alias = (s->angles_rad - truth).norm() < 1e-3 ? s->alternative_rad : s->angles_rad;
    const AliasEvidence a = with.aliasEvidence(image, truth, alias), b = without.aliasEvidence(image, truth, alias);
    EXPECT_NEAR(a.z, b.z, 0.5 * PatternEstimator::kCanvasZMargin) << angles.transpose();
    EXPECT_NEAR(a.unexplained_z, b.unexplained_z,
                0.5 * (PatternEstimator::kExcessNoiseZ - PatternEstimator::kCanvasMaxUnexplainedZ))
        << angles.transpose();
    const SunEstimate e = with.estimateOne(image), f = without.estimateOne(image);
    ASSERT_TRUE(e.valid && f.valid) << e.status << " / " << f.status;
    EXPECT_EQ(e.alpha_rad, f.alpha_rad);
    EXPECT_EQ(e.beta_rad, f.beta_rad);
    EXPECT_EQ(e.covariance, f.covariance);
  }
}

// Where the pattern's two places are mirror images of each other (alpha
// about +-2.87 deg, 5.74 deg apart), the design's image cannot tell them
// apart through the detector's noise and the image alone is declined; a coarse direction (a coarse sun
// sensor) nearer one place by 3 of its sigma chooses that place, one about
// midway leaves it declined.
TEST_F(PatternSolveTest, MirrorImageAliasIsChosenByACoarseDirection) {
  PatternEstimator estimator(*config_, kNoSigmaImages);
  // With the detector's noise (every seed of 1-12 is declined alone; with
  // seed 2 the solve lands at the alias first).
  const cv::Mat image = renderer_->render(sunVectorFromAngles(degToRad(2.87), degToRad(0.1)), 2, nullptr);
  const SunEstimate alone = estimator.estimate({image}).at(0);
  EXPECT_FALSE(alone.valid);
  EXPECT_EQ(status::statusCode(alone.status), status::kAmbiguousAperture) << alone.status;
  const auto withCoarse = [&](double alpha_deg) {
    return estimator
        .estimateWithCoarseDirections({image}, {CoarseDirection{degToRad(alpha_deg), degToRad(0.5), degToRad(1.0)}})
        .at(0);
  };
  const SunEstimate near_truth = withCoarse(4.0);
  ASSERT_TRUE(near_truth.valid) << near_truth.status;
  EXPECT_NEAR(radToDeg(near_truth.alpha_rad), 2.87, 0.002);
  EXPECT_NEAR(radToDeg(near_truth.beta_rad), 0.1, 0.002);
  const SunEstimate near_alias = withCoarse(-2.0);  // trusted, and wrong
  ASSERT_TRUE(near_alias.valid) << near_alias.status;
  EXPECT_NEAR(radToDeg(near_alias.alpha_rad), 2.87 - 5.74, 0.05);
  const SunEstimate midway = withCoarse(0.3);
  EXPECT_FALSE(midway.valid);
  EXPECT_EQ(status::statusCode(midway.status), status::kAmbiguousAperture) << midway.status;
  EXPECT_THROW(estimator.estimateWithCoarseDirections({image, image}, {std::nullopt}), std::invalid_argument);
}

// Where no alias competes, a ghost still biases the solve beyond its
// sigma: the answer is declined model_mismatch when the image holds light
// the design's image at the answer does not; the same unit without the
// ghost is answered.
TEST_F(PatternSolveTest, AnswerIsDeclinedWhereLightTheDesignLacksRemains) {
  const PatternEstimator estimator(*config_, kNoSigmaImages);
  const Eigen::Vector2d truth(degToRad(0.6), degToRad(2.0));
  const auto [clean, ghosted] = withAndWithoutGhost(truth, 9);
  EXPECT_LT(estimator.unexplainedLightZ(clean, truth), AliasEvidence::kMaxUnexplainedZ);
  EXPECT_GT(estimator.unexplainedLightZ(ghosted, truth), AliasEvidence::kMaxUnexplainedZ);
  const SunEstimate answered = estimator.estimateOne(clean);
  ASSERT_TRUE(answered.valid) << answered.status;
  EXPECT_NEAR(radToDeg(answered.alpha_rad), 0.6, 2e-3);
  const SunEstimate declined = estimator.estimateOne(ghosted);
  EXPECT_FALSE(declined.valid);
  EXPECT_EQ(status::statusCode(declined.status), status::kModelMismatch) << declined.status;
}

// A ghost whose excess stays below the decline still biases the answer
// beyond the solve's sigma: the answer's variance grows with the excess.
TEST_F(PatternSolveTest, AnswerHoldingSomeLightTheDesignLacksHasItsVarianceGrown) {
  const PatternEstimator estimator(*config_, kNoSigmaImages);
  const auto [clean, ghosted] = withAndWithoutGhost(Eigen::Vector2d(degToRad(1.5), degToRad(-1.0)), 2);
  const SunEstimate e = estimator.estimateOne(ghosted);
  ASSERT_TRUE(e.valid) << e.status;
  EXPECT_GT(e.unexplained_light_z, PatternEstimator::kExcessNoiseZ + 0.5);
  EXPECT_LE(e.unexplained_light_z, AliasEvidence::kMaxUnexplainedZ);
  // The solve's own answer (its alias decided for its best fit), the variance times the excess's inflation.
  const auto solved = solver_->solve(ghosted);
  ASSERT_TRUE(solved);
  EXPECT_EQ(e.alpha_rad, solved->angles_rad.x());
  const double inflation = PatternEstimator::varianceInflation(e.unexplained_light_z);
  EXPECT_GT(inflation, 2.5);
  EXPECT_NEAR(e.covariance[0] / solved->covariance(0, 0), inflation, 1e-9 * inflation);
  EXPECT_NEAR(e.covariance[3] / solved->covariance(1, 1), inflation, 1e-9 * inflation);
}

TEST(PatternEstimatorSigma, VarianceGrowsWithTheExcessAboveItsNoise) {
  EXPECT_EQ(PatternEstimator::varianceInflation(-3.0), 1.0);
  EXPECT_EQ(PatternEstimator::varianceInflation(PatternEstimator::kExcessNoiseZ), 1.0);
  EXPECT_DOUBLE_EQ(PatternEstimator::varianceInflation(PatternEstimator::kExcessNoiseZ + 2.0),
                   1.0 + 2.0 * PatternEstimator::kVariancePerExcess);
}

// The solve's sigma takes the residual as independent pixel noise; on the
// design's own noisy images the errors are larger than that (the
// template's error is correlated over the pattern): the scale measured at
// construction says by how much, and the covariance carries it.
TEST_F(PatternSolveTest, SigmaScaleIsMeasuredOnTheDesignsOwnImages) {
  PatternEstimatorOptions options;
  options.sigma_images = 12;
  const PatternEstimator estimator(*config_, options);
  for (double scale : estimator.sigmaScale()) {
    EXPECT_GT(scale, 1.0);
    EXPECT_LT(scale, 4.0);
  }
  const PatternEstimator unscaled(*config_, kNoSigmaImages);
  const cv::Mat image = noiseFree(*renderer_, 0.3, -0.2);
  const SunEstimate a = estimator.estimateOne(image), b = unscaled.estimateOne(image);
  ASSERT_TRUE(a.valid && b.valid);
  EXPECT_NEAR(a.covariance[0] / b.covariance[0], estimator.sigmaScale()[0] * estimator.sigmaScale()[0], 1e-9);
  EXPECT_NEAR(a.covariance[3] / b.covariance[3], estimator.sigmaScale()[1] * estimator.sigmaScale()[1], 1e-9);
}

TEST_F(PatternSolveTest, BadImagesAndHintsAreRefusedByName) {
  PatternEstimator estimator(*config_, kNoSigmaImages);
  EXPECT_EQ(status::statusCode(estimator.estimateOne(cv::Mat::zeros(10, 10, CV_8U)).status), status::kBadImage);
  EXPECT_EQ(estimator.estimateOne(cv::Mat::zeros(512, 512, CV_8U)).status, status::kNoSun);
  EXPECT_THROW(estimator.estimateWithSubFovHints({cv::Mat::zeros(512, 512, CV_8U)}, {}), std::invalid_argument);
  EXPECT_THROW(estimator.estimateWithSubFovHints({cv::Mat::zeros(512, 512, CV_8U)}, {7}), std::invalid_argument);
}

TEST(PatternEstimatorWarmUp, ComputesTheDesignsSpotsBeforeTheFirstImage) {
  // thesis_ca on a +-1 deg field with 2 deg diffraction nodes: its own cache
  // (the node step is part of its key), nine nodes over the field.
  const SensorConfig small = loadSensorConfig(
      shippedPath("thesis_ca"), {"fov.alpha_max_deg=1", "fov.beta_max_deg=1", "optics.psf_node_step_deg=2"});
  const PatternEstimator estimator(small, kNoSigmaImages);
  const Renderer probe(SensorInstance::nominalOf(small));  // shares the design's cache
  ASSERT_LT(probe.spotCache().nodesHeld(), 9u);            // the template's node only
  const SunEstimator& as_estimator = estimator;
  as_estimator.warmUp(2);
  EXPECT_EQ(probe.spotCache().nodesHeld(), 9u);
  // An image and its estimate (the design's image at the answer) need no new node.
  const SunEstimate e = estimator.estimateOne(noiseFree(probe, 0.4, -0.6));
  EXPECT_TRUE(e.valid) << e.status;
  EXPECT_NEAR(radToDeg(e.alpha_rad), 0.4, 1e-3);
  EXPECT_EQ(probe.spotCache().nodesHeld(), 9u);
}

}  // namespace
}  // namespace dss
