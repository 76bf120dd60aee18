// The reference consistency (estimate/reference_consistency): estimates that
// agree with their references within sigma are left alone, a common offset
// far beyond sigma (a drifted unit) widens sigma to hold it, gross
// references do not, and a refit starts the judgement afresh.
#include <gtest/gtest.h>

#include <cmath>

#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/estimate/reference_consistency.h"

namespace dss {
namespace {

constexpr double kSigmaDeg = 0.0005;

// An estimate of `truth` off by `offset_deg` plus noise of its own sigma.
SunEstimate estimateOf(const std::array<double, 2>& truth, const std::array<double, 2>& offset_deg, Rng& rng) {
  SunEstimate e;
  e.valid = true;
  e.alpha_rad = truth[0] + degToRad(offset_deg[0] + kSigmaDeg * rng.normal());
  e.beta_rad = truth[1] + degToRad(offset_deg[1] + kSigmaDeg * rng.normal());
  e.covariance = {std::pow(degToRad(kSigmaDeg), 2), 0.0, 0.0, std::pow(degToRad(kSigmaDeg), 2)};
  return e;
}

std::array<double, 2> drawTruth(Rng& rng) {
  return {degToRad(rng.uniform(-5.0, 5.0)), degToRad(rng.uniform(-5.0, 5.0))};
}

TEST(ReferenceConsistency, LeavesConsistentEstimatesAlone) {
  ConsistencyOptions options;
  options.reference_sigma_deg = 0.0;
  ReferenceConsistency consistency(options);
  Rng rng(3);
  int widened = 0;
  for (int i = 0; i < 2000; ++i) {
    const auto truth = drawTruth(rng);
    // One reference in twenty grossly wrong (a star tracker outlier).
    std::array<double, 2> reference = truth;
    if (i % 20 == 7) reference[0] += degToRad(3.0);
    consistency.add(estimateOf(truth, {0.0, 0.0}, rng), reference);
    widened += consistency.inconsistent();
  }
  EXPECT_EQ(widened, 0);
  EXPECT_NEAR(consistency.normalizedRms()[1], 1.0, 0.4);
  SunEstimate e = estimateOf({0.0, 0.0}, {0.0, 0.0}, rng);
  const SunEstimate before = e;
  consistency.widen(e);
  EXPECT_EQ(e.covariance, before.covariance);
}

TEST(ReferenceConsistency, WidensSigmaToHoldADriftUntilReset) {
  ConsistencyOptions options;
  options.reference_sigma_deg = 0.0;
  ReferenceConsistency consistency(options);
  Rng rng(4);
  const std::array<double, 2> drift_deg = {0.05, 0.002};  // 100 and 4 sigma
  for (std::size_t i = 0; i < options.min_pairs - 1; ++i) {
    const auto truth = drawTruth(rng);
    consistency.add(estimateOf(truth, drift_deg, rng), truth);
  }
  EXPECT_FALSE(consistency.inconsistent()) << "judged before min_pairs";
  int held = 0, tried = 0;
  for (int i = 0; i < 200; ++i) {
    const auto truth = drawTruth(rng);
    std::array<double, 2> reference = truth;
    if (i % 20 == 7) reference[1] -= degToRad(4.0);
    SunEstimate e = estimateOf(truth, drift_deg, rng);
    consistency.add(e, reference);
    ASSERT_TRUE(consistency.inconsistent());
    consistency.widen(e);
    ++tried;
    held += std::abs(e.alpha_rad - truth[0]) <= 3.0 * std::sqrt(e.covariance[0]) &&
            std::abs(e.beta_rad - truth[1]) <= 3.0 * std::sqrt(e.covariance[3]);
  }
  EXPECT_EQ(held, tried);
  // The robust RMS reads a residual that is the same in every pair as 1.48
  // times itself (it assumes them normal): conservative, never short.
  EXPECT_GT(radToDeg(consistency.extraSigmaRad()[0]), drift_deg[0]);
  EXPECT_LT(radToDeg(consistency.extraSigmaRad()[0]), 1.6 * drift_deg[0]);
  EXPECT_GT(consistency.extraSigmaRad()[1], 0.0);
  EXPECT_GT(consistency.normalizedRms()[0], 50.0);

  consistency.reset();
  EXPECT_FALSE(consistency.inconsistent());
  EXPECT_EQ(consistency.pairs(), 0u);
  SunEstimate e = estimateOf({0.0, 0.0}, drift_deg, rng);
  consistency.widen(e);
  EXPECT_DOUBLE_EQ(e.covariance[0], std::pow(degToRad(kSigmaDeg), 2));
}

TEST(ReferenceConsistency, RefusesBadOptions) {
  ConsistencyOptions options;
  options.min_pairs = 2;
  EXPECT_THROW(ReferenceConsistency{options}, std::invalid_argument);
  options = {};
  options.window = options.min_pairs - 1;
  EXPECT_THROW(ReferenceConsistency{options}, std::invalid_argument);
  options = {};
  options.max_normalized = 0.0;
  EXPECT_THROW(ReferenceConsistency{options}, std::invalid_argument);
}

}  // namespace
}  // namespace dss
