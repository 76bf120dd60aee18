// The tracking prior (estimate/tracking_prior): the last answer as a coarse
// direction whose sigma grows with the rate bound and the time since; the
// bound holds for any motion of the sun within it, anywhere in a wide field;
// stale, earlier and invalid answers give none; far answers contradict it,
// and one that did gives none.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <stdexcept>

#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/estimate/tracking_prior.h"
#include "digital_sun_sensor/sim/geometry.h"

namespace dss {
namespace {

SunEstimate answerAt(double alpha_deg, double beta_deg, double sigma_deg = 0.0002) {
  SunEstimate e;
  e.valid = true;
  e.alpha_rad = degToRad(alpha_deg);
  e.beta_rad = degToRad(beta_deg);
  const double variance = std::pow(degToRad(sigma_deg), 2);
  e.covariance = {variance, 0.0, 0.0, variance};
  return e;
}

// The same answer three times, 0.01 s apart: the last two agree with the one before.
void answerThrice(TrackingPrior& prior, double stamp_s, const SunEstimate& answer) {
  for (double before_s : {0.02, 0.01, 0.0}) prior.update(stamp_s - before_s, answer);
}

TrackingOptions trackingAt(double max_rate_deg_s, double max_age_s = 1.0) {
  TrackingOptions options;
  options.max_rate_deg_s = max_rate_deg_s;
  options.max_age_s = max_age_s;
  return options;
}

TEST(TrackingPrior, OffUnlessARateBoundIsGiven) {
  TrackingPrior prior;
  answerThrice(prior, 10.0, answerAt(2.0, 0.1));
  EXPECT_FALSE(prior.at(10.01));
}

TEST(TrackingPrior, SigmaIsTheAnswersPlusTheRateBoundTimesTheAge) {
  TrackingPrior prior(trackingAt(10.0));
  answerThrice(prior, 10.0, answerAt(2.0, 0.1, 0.0002));
  const auto now = prior.at(10.0);
  ASSERT_TRUE(now);
  EXPECT_NEAR(radToDeg(now->alpha_rad), 2.0, 1e-12);
  EXPECT_NEAR(radToDeg(now->beta_rad), 0.1, 1e-12);
  EXPECT_NEAR(radToDeg(now->sigma_rad), 0.0002, 1e-12);
  // 0.05 s at 10 deg/s: 0.5 deg on the sky, a little more in alpha 2 deg off axis.
  const auto later = prior.at(10.05);
  ASSERT_TRUE(later);
  EXPECT_GT(radToDeg(later->sigma_rad), 0.5002);
  EXPECT_LT(radToDeg(later->sigma_rad), 0.5002 * 1.01);
}

// Any motion of the sun by up to the bound's turn moves alpha and beta by
// less than the prior's sigma, also at 60 deg off axis, where a turn on the
// sky moves the angles by up to twice as much.
TEST(TrackingPrior, BoundsTheAnglesOfEveryMotionWithinTheRate) {
  const double rate_deg_s = 20.0, age_s = 0.25;
  TrackingPrior prior(trackingAt(rate_deg_s));
  Rng rng(11);
  int tight = 0;
  for (int k = 0; k < 4000; ++k) {
    const double alpha = degToRad(rng.uniform(-60.0, 60.0)), beta = degToRad(rng.uniform(-60.0, 60.0));
    answerThrice(prior, 0.0, answerAt(radToDeg(alpha), radToDeg(beta), 0.0));
    const auto p = prior.at(age_s);
    ASSERT_TRUE(p);
    // A turn of up to rate x age about a random axis.
    const Eigen::Vector3d axis = Eigen::Vector3d(rng.normal(), rng.normal(), rng.normal()).normalized();
    const double turn = degToRad(rate_deg_s * age_s) * rng.uniform(0.0, 1.0);
    const Eigen::Vector3d moved = Eigen::AngleAxisd(turn, axis) * sunVectorFromAngles(alpha, beta);
    const SunAnglesRad angles = anglesFromSunVector(moved);
    const double change = std::max(std::abs(angles.alpha - alpha), std::abs(angles.beta - beta));
    ASSERT_LE(change, p->sigma_rad) << radToDeg(alpha) << ", " << radToDeg(beta);
    tight += change > 0.8 * p->sigma_rad;
  }
  EXPECT_GT(tight, 10) << "the bound is not loose everywhere";
}

TEST(TrackingPrior, NoPriorWhenStaleEarlierOrFromAnInvalidAnswer) {
  TrackingPrior prior(trackingAt(5.0, 0.5));
  SunEstimate declined = answerAt(2.87, 0.1);
  declined.valid = false;
  prior.update(10.0, declined);
  EXPECT_FALSE(prior.at(10.1)) << "a declined image gives no prior";
  answerThrice(prior, 10.0, answerAt(2.0, 0.1));
  EXPECT_TRUE(prior.at(10.5));
  EXPECT_FALSE(prior.at(10.51)) << "older than max_age_s";
  EXPECT_FALSE(prior.at(9.99)) << "an image before the answer";
  // A replay that starts over: the latest answers are the prior, whatever their stamps.
  answerThrice(prior, 3.0, answerAt(-1.0, 0.0));
  const auto restarted = prior.at(3.1);
  ASSERT_TRUE(restarted);
  EXPECT_NEAR(radToDeg(restarted->alpha_rad), -1.0, 1e-12);
}

TEST(TrackingPrior, AnAnswerFartherThanTheBoundAllowsContradictsIt) {
  TrackingPrior prior(trackingAt(1.0));
  EXPECT_FALSE(prior.contradicts(10.1, answerAt(-2.87, 0.1))) << "no answer yet";
  prior.update(10.0, answerAt(2.87, 0.1, 0.0002));
  // 0.1 s at 1 deg/s: 0.1 deg, plus 5 sigma of two answers' difference (0.0014 deg).
  EXPECT_FALSE(prior.contradicts(10.1, answerAt(2.97, 0.1, 0.0002)));
  EXPECT_FALSE(prior.contradicts(10.1, answerAt(2.87, 0.0, 0.0002)));
  EXPECT_TRUE(prior.contradicts(10.1, answerAt(2.975, 0.1, 0.0002)));
  EXPECT_TRUE(prior.contradicts(10.1, answerAt(-2.87, 0.1))) << "the mirror-image place, 5.74 deg away";
  EXPECT_FALSE(prior.contradicts(10.0, answerAt(2.8705, 0.1, 0.0002))) << "the same moment: noise alone";
}

// A sun faster than the bound: an answer far from the prior gives none
// (the mirror-image place would be chosen from where the sun was), until
// the next answer agrees with it.
TEST(TrackingPrior, GivesNoneUntilTwoAnswersInARowKeptWithinTheBound) {
  TrackingPrior prior(trackingAt(1.0));
  prior.update(10.0, answerAt(2.0, 0.1));
  EXPECT_FALSE(prior.at(10.1)) << "one answer: nothing has shown the motion within the bound yet";
  prior.update(10.1, answerAt(2.05, 0.1));
  EXPECT_FALSE(prior.at(10.2));
  prior.update(10.2, answerAt(2.1, 0.1));
  EXPECT_TRUE(prior.at(10.3));
  prior.update(10.3, answerAt(-2.0, 0.1));  // 4 deg in 0.1 s
  EXPECT_FALSE(prior.at(10.4));
  prior.update(10.4, answerAt(-2.05, 0.1));
  EXPECT_FALSE(prior.at(10.5));
  prior.update(10.5, answerAt(-2.1, 0.1));
  EXPECT_TRUE(prior.at(10.6));
}

TEST(TrackingPrior, RefusesBadOptions) {
  EXPECT_THROW(TrackingPrior(trackingAt(-1.0)), std::invalid_argument);
  EXPECT_THROW(TrackingPrior(trackingAt(std::nan(""))), std::invalid_argument);
  EXPECT_THROW(TrackingPrior(trackingAt(5.0, 0.0)), std::invalid_argument);
}

}  // namespace
}  // namespace dss
