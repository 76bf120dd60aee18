// The conventional baseline: centroids on noise-free images, association on
// single, multi-aperture, coded and wide-field masks, recovery of as-built
// errors by the calibration fit, and the calibration file.
#include <gtest/gtest.h>

#include <cmath>

#include "digital_sun_sensor/baseline/calibration_fit.h"
#include "digital_sun_sensor/baseline/centroid_estimator.h"
#include "digital_sun_sensor/baseline/gaussian_fit.h"
#include "digital_sun_sensor/baseline/geometry_fit.h"
#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/common/spike_filter.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/sim/dataset_generator.h"
#include "digital_sun_sensor/sim/geometry.h"

namespace dss {
namespace {

SensorConfig shipped(const std::string& name, const std::vector<std::string>& overrides = {}) {
  return loadSensorConfig(std::string(DSS_SOURCE_DIR) + "/config/sensors/" + name + ".yaml", overrides);
}

// Exact synthetic spots (pixel-integrated Gaussians, 16-bit, no noise) at
// sub-pixel offsets: the centroid methods themselves add (almost) nothing.
TEST(Centroid, ExactSyntheticSpots) {
  SpotExtractionConfig extraction;
  extraction.relative_threshold = 0.0;
  extraction.threshold_dn = 0.5;
  for (const auto method : {CentroidMethod::kWeighted, CentroidMethod::kGaussianFit}) {
    extraction.method = method;
    double worst = 0.0;
    for (int k = 0; k < 10; ++k) {
      const GaussianSpot truth{30.0 + 0.137 * k, 25.0 - 0.091 * k, 2.0, 1.0e6, 0.0};
      cv::Mat image;
      renderGaussianSpot(truth, 50, 60).convertTo(image, CV_16U);  // rounds to integer DN
      const auto spots = extractSpots(image, extraction);
      ASSERT_EQ(spots.size(), 1u);
      worst = std::max({worst, std::abs(spots[0].x_px + 29.5 - truth.x), std::abs(spots[0].y_px + 24.5 - truth.y)});
    }
    EXPECT_LT(worst, 1e-3) << toString(method);
  }
}

// Noise-free, nominal, full physics: the centroid of the spot sits on its true
// centre. Raw 16-bit readout, most of the spot used (2% of the peak up): the
// energy centroid follows the ray. Not shown here, measured with `dss eval`:
// the thesis sensors keep only the top 10% (on-chip threshold, 8 bit), whose
// core is slightly asymmetric at oblique incidence (~0.007 px RMS, smooth in
// angle: the residual polynomial absorbs it). Vignetting off: with it, the
// mask thickness shifts the transmitted beam by design (the fitted height
// absorbs that; see CalibrationFit below).
TEST(Centroid, NoiseFreeErrorWellBelowOneHundredthPixel) {
  const SensorConfig config =
      shipped("thesis_sa", {"optics.vignetting=false", "detector_noise.bit_depth=16", "threshold.enabled=false"});
  const Renderer renderer(SensorInstance::nominalOf(config));
  RenderOptions options;
  options.noise = false;
  Rng rng(5);
  SpotExtractionConfig extraction = SpotExtractionConfig::forSensor(config);
  extraction.relative_threshold = 0.02;
  double worst = 0.0, sum_sq = 0.0;
  int n = 0;
  for (int i = 0; i < 20; ++i) {
    ImageTruth truth;
    // Inside +-3.5 deg the whole spot, halo included, stays on the detector.
    const Eigen::Vector3d sun =
        sunVectorFromAngles(rng.uniform(-3.5, 3.5) * kRadPerDeg, rng.uniform(-3.5, 3.5) * kRadPerDeg);
    const cv::Mat image = renderer.render(sun, 1, &truth, options);
    const auto spots = extractSpots(image, extraction);
    ASSERT_EQ(spots.size(), 1u);
    const double ex = spots[0].x_px - truth.spots[0].x_px, ey = spots[0].y_px - truth.spots[0].y_px;
    worst = std::max({worst, std::abs(ex), std::abs(ey)});
    sum_sq += ex * ex + ey * ey;
    ++n;
  }
  const double rms = std::sqrt(sum_sq / (2 * n));
  // Measured: 0.0018 px RMS, 0.0039 px worst.
  EXPECT_LT(rms, 0.003);
  EXPECT_LT(worst, 0.005);
}

// Spots placed exactly where the design puts them (plus 0.05 px noise), sizes
// following aperture area, edge spots cut: association must name every
// aperture right and recover the sun. Multi-aperture (3x3 lattice: one pitch
// of shift is only told apart by the spots that should be visible), coded
// (117 apertures) and wide-field with coded diameters behind glass.
TEST(Association, RecoversAperturesOnEveryMask) {
  for (const std::string name : {"thesis_ma", "thesis_ca", "wide_ma"}) {
    const SensorConfig config = shipped(name);
    const MaskGeometry geometry = MaskGeometry::nominalOf(config);
    const AssociationOptions options = AssociationOptions::forSensor(config, geometry);
    Rng rng(17);
    int trials = 0, correct = 0;
    for (int t = 0; t < 200; ++t) {
      // The coded mask's three groups are copies shifted by 325 px: beyond
      // |alpha| ~ 1.2 deg, with one group off the detector, a shift by one
      // group explains the image equally well. Only the sub-FOV class could
      // tell (the published SSCNN takes it as an input); keep to the
      // unambiguous band there.
      const double alpha_max = name == "thesis_ca" ? 1.0 : config.fov.alpha_max_deg;
      const double alpha = rng.uniform(-1.0, 1.0) * alpha_max * kRadPerDeg;
      const double beta = rng.uniform(-1.0, 1.0) * config.fov.beta_max_deg * kRadPerDeg;
      const Eigen::Vector3d sun = sunVectorFromAngles(alpha, beta);
      std::vector<DetectedSpot> spots;
      std::vector<int> truth;
      for (int i = 0; i < geometry.numApertures(); ++i) {
        const auto p = geometry.spotPx(i, sun);
        if (!p || !geometry.insideDetector(*p, -0.5 * options.edge_margin_px)) continue;
        if (!geometry.insideDetector(*p, options.edge_margin_px)) {
          // Cut by the edge: seen, centroid pulled inward, not for solving.
          DetectedSpot cut;
          cut.x_px = p->x() * 0.95;
          cut.y_px = p->y() * 0.95;
          cut.area_px = 50;
          cut.touches_edge = true;
          spots.push_back(cut);
          truth.push_back(-1);
          continue;
        }
        DetectedSpot s;
        s.x_px = p->x() + 0.05 * rng.normal();
        s.y_px = p->y() + 0.05 * rng.normal();
        s.area_px = static_cast<int>(std::round(0.1 * std::pow(geometry.aperture_diameters_um[i], 2)));
        s.flux_dn = s.area_px * 200.0;
        spots.push_back(s);
        truth.push_back(i);
      }
      const auto whole =
          static_cast<std::size_t>(std::count_if(truth.begin(), truth.end(), [](int i) { return i >= 0; }));
      if (whole == 0) continue;
      ++trials;
      const auto a = associateSpots(geometry, spots, options);
      if (!a || a->observations.size() != whole) {
        std::printf("%s a=%.3f b=%.3f spots %zu assoc %d obs %zu\n", name.c_str(), alpha / kRadPerDeg,
                    beta / kRadPerDeg, spots.size(), !!a, a ? a->observations.size() : 0);
        continue;
      }
      bool right = true;
      for (std::size_t k = 0; k < a->observations.size(); ++k)
        right &= a->observations[k].aperture == truth[a->spot_indices[k]];
      // 0.05 px of centroid noise moves the solution by ~0.05 px x pitch / height.
      const double tolerance = 20.0 * 0.05 * geometry.pitch_um / geometry.height_um;
      right &= std::abs(a->solution.alpha_rad - alpha) < tolerance && std::abs(a->solution.beta_rad - beta) < tolerance;
      correct += right;
    }
    EXPECT_GT(trials, 150) << name;
    EXPECT_GE(correct, trials - 1) << name << ": " << correct << " of " << trials;
  }
}

// A sensor with manufacturing errors well beyond the nominal tolerances,
// imaged with full noise: the fit recovers what is observable, each
// aperture's centre in the sensor frame (which is what rotation, offset and
// per-aperture errors amount to), the mask height and its tilt.
// Tolerances: 0.1 px centroid noise over ~9 spots x 150 images gives ~0.02 um
// on positions and ~0.1 um on height (lever arm tan(angle) ~ 0.05); the
// asserted bounds leave 5-10x for systematic spot-shape effects.
TEST(CalibrationFit, RecoversAsBuiltErrors) {
  const SensorConfig config =
      shipped("thesis_ma", {"optics.vignetting=false", "optics.psf_node_step_deg=2.5", "as_built.height_sigma_um=50",
                            "as_built.offset_sigma_um=20", "as_built.rotation_sigma_deg=0.5",
                            "as_built.tilt_sigma_deg=0.3", "as_built.aperture_position_sigma_um=3"});
  const SensorInstance sensor = SensorInstance::draw(config, 4242);
  const Renderer renderer(sensor);
  const AttitudeSampler sampler(config, SamplingMode::kRandom, 9);
  Calibration calibration = Calibration::nominalOf(config);
  std::vector<CalibrationSample> samples;
  for (int i = 0; i < 150; ++i) {
    const Eigen::Vector3d sun = sampler.sunVector(i);
    samples.push_back({sun, extractSpots(renderer.render(sun, 100 + i, nullptr), calibration.extraction)});
  }
  const CalibrationFitReport report = fitCalibration(samples, calibration);
  std::printf("design %.3f px -> fitted %.4f px, %d obs, %d outliers, angle rms %.6f deg\n", report.rms_px_design,
              report.rms_px_fitted, report.observations, report.outliers, report.angle_rms_deg);
  EXPECT_GT(report.rms_px_design, 5.0);  // the errors matter: many pixels before the fit
  EXPECT_LT(report.rms_px_fitted, 0.2);
  double worst_xy = 0.0, worst_z = 0.0;
  for (int i = 0; i < calibration.geometry.numApertures(); ++i) {
    const Eigen::Vector3d d = calibration.geometry.apertureCentreUm(i) - sensor.apertureCentreUm(i);
    worst_xy = std::max(worst_xy, d.head<2>().norm());
    worst_z = std::max(worst_z, std::abs(d.z()));
  }
  std::printf("worst aperture error: xy %.4f um, z %.4f um\n", worst_xy, worst_z);
  EXPECT_LT(worst_xy, 0.2);
  EXPECT_LT(worst_z, 1.0);
  // The tilt itself, from the height differences across the mask.
  const Eigen::Vector3d normal_true = sensor.mask_rotation.col(2),
                        normal_fit = maskRotation(calibration.geometry.rotation_rad, calibration.geometry.tilt_x_rad,
                                                  calibration.geometry.tilt_y_rad)
                                         .col(2);
  // ~0.2 um of height noise per aperture over a 530 um baseline: ~0.03 deg.
  const double tilt_true_deg = std::acos(normal_true.z()) / kRadPerDeg;
  const double tilt_error_deg = std::acos(std::min(1.0, normal_true.dot(normal_fit))) / kRadPerDeg;
  std::printf("tilt %.3f deg, error %.4f deg\n", tilt_true_deg, tilt_error_deg);
  EXPECT_GT(tilt_true_deg, 0.1);
  EXPECT_LT(tilt_error_deg, 0.1);
  EXPECT_LT(report.angle_rms_deg, 0.002);
}

TEST(GeometryFit, EachApertureHeldByItsOwnPrior) {
  // Spots of the thesis_ma lattice with one aperture 2 um off its design
  // place, with a little noise. Under the weak gauge prior the fit follows
  // that aperture; held by a strong prior of its own (a place known from an
  // earlier calibration) it stays, and its variance says how well it is known.
  const SensorConfig config = shipped("thesis_ma");
  const MaskGeometry design = MaskGeometry::nominalOf(config);
  MaskGeometry truth = design;
  truth.apertures_um[4] += Eigen::Vector2d(2.0, -2.0);
  Rng rng(23);
  std::vector<GeometryObservation> obs;
  for (int i = 0; i < 60; ++i) {
    const Eigen::Vector3d sun = sunVectorFromAngles(degToRad(rng.uniform(-4, 4)), degToRad(rng.uniform(-4, 4)));
    for (int k = 0; k < design.numApertures(); ++k) {
      const auto px = truth.spotPx(k, sun);
      if (!px || !truth.insideDetector(*px, 10.0)) continue;
      GeometryObservation o;
      o.sample = i;
      o.sun = sun;
      o.apertures = {k};
      o.measured_px = *px + Eigen::Vector2d(0.002 * rng.normal(), 0.002 * rng.normal());
      obs.push_back(o);
    }
  }
  const double gauge = 1e-6;  // a 0.002 px noise against a 2 px prior
  std::vector<double> held(static_cast<std::size_t>(design.numApertures()), gauge);
  held[4] = 1e6;
  const auto fitted = [&](const GeometryFit& fit) {
    Eigen::VectorXd p = fit.start();
    fit.run(p, obs, 100);
    return std::pair{fit.apply(p), fit.apertureVariances(p, obs)};
  };
  const auto [free_fit, free_variance] = fitted(GeometryFit(design, gauge));
  const auto [held_fit, held_variance] = fitted(GeometryFit(design, 0.0, held));
  const auto moved = [&](const MaskGeometry& g) { return (g.apertures_um[4] - design.apertures_um[4]).norm(); };
  std::printf("aperture 4 moved %.4f um (weak prior), %.6f um (held); variance %.3g / %.3g px^2\n", moved(free_fit),
              moved(held_fit), free_variance[4], held_variance[4]);
  EXPECT_GT(moved(free_fit), 2.0);  // of 2.83 (the gauge prior shares some with the common terms)
  EXPECT_LT(moved(held_fit), 0.01);
  EXPECT_LT(held_variance[4], 0.01 * free_variance[4]);
  for (std::size_t k = 0; k < free_variance.size(); ++k) EXPECT_LT(free_variance[k], 1e-4) << "aperture " << k;
  EXPECT_THROW(GeometryFit(design, gauge, {1.0, 2.0}), std::invalid_argument);
}

TEST(CalibrationFile, RoundTripAndClearErrors) {
  Calibration c = Calibration::nominalOf(shipped("thesis_ma"));
  c.geometry.height_um = 5012.345678901;
  c.geometry.tilt_x_rad = 1.25e-3;
  c.geometry.apertures_um[4] = Eigen::Vector2d(0.123456789, -0.987654321);
  c.polynomial.degree = 2;
  c.polynomial.alpha_coefficients = {1e-6, 2e-6, 3e-6, 4e-6, 5e-6, 6e-6};
  c.polynomial.beta_coefficients = {-1e-6, -2e-6, -3e-6, -4e-6, -5e-6, -6e-6};
  c.centroid_sigma_px = 0.07;
  const std::string text = toYaml(c);
  const Calibration back = parseCalibration(text, "mem");
  EXPECT_EQ(back.geometry.height_um, c.geometry.height_um);
  EXPECT_EQ(back.geometry.tilt_x_rad, c.geometry.tilt_x_rad);
  EXPECT_EQ(back.geometry.apertures_um[4], c.geometry.apertures_um[4]);
  EXPECT_EQ(back.polynomial.beta_coefficients, c.polynomial.beta_coefficients);
  EXPECT_EQ(back.centroid_sigma_px, c.centroid_sigma_px);
  EXPECT_EQ(toYaml(back), text);

  auto expectError = [](const std::string& yaml, const std::string& needle) {
    try {
      parseCalibration(yaml, "calib.yaml");
      ADD_FAILURE() << "accepted: " << needle;
    } catch (const CalibrationError& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("calib.yaml"), std::string::npos) << e.what();
    }
  };
  auto replaced = [&](const std::string& from, const std::string& to) {
    std::string t = text;
    t.replace(t.find(from), from.size(), to);
    return t;
  };
  expectError("[unclosed", "not valid YAML");
  expectError("format: something_else\n", "not a dss calibration file");
  expectError(replaced("version: 1", "version: 9"), "version 9");
  expectError(replaced("height_um: 5012", "height_um: -5012"), "height_um must be > 0");
  expectError(replaced("centroid_sigma_px", "centroid_sigma"), "centroid_sigma_px");
  expectError(replaced("degree: 2", "degree: 3"), "needs 10 coefficients");
  expectError(replaced("  apertures:\n    - {", "  apertures:\n    - {x_um: 1, y_um: 2}\n    - {"), "must list 9");
  expectError(replaced("spike_sigmas: 4", "spike_sigmas: -4"), "spike_sigmas must be >= 0");
  // A key the format does not have is refused with its path, not ignored.
  expectError(replaced("spike_sigmas: 4", "spike_sigma: 4"), "extraction.spike_sigma: unknown key");
  // Files from before the hot-pixel repair have no spike_sigmas: the default.
  const Calibration old = parseCalibration(replaced("\n  spike_sigmas: 4", ""), "old.yaml");
  EXPECT_EQ(old.extraction.spike_sigmas, kDefaultSpikeSigmas);
  EXPECT_EQ(old.extraction.spike_margin_dn, c.extraction.spike_margin_dn);
  EXPECT_TRUE(
      parseCalibration(replaced("spike_sigmas: 4", "spike_sigmas: 0"), "off.yaml").extraction.spike_margin_dn.empty());
  EXPECT_THROW(loadCalibration("/nonexistent/calib.yaml"), CalibrationError);
}

// Bad images are answered with valid = false and a reason, never a crash.
TEST(CentroidEstimator, BadImagesGetAReason) {
  CentroidEstimator estimator(Calibration::nominalOf(shipped("thesis_sa")));
  const auto estimates = estimator.estimate(
      {cv::Mat(), cv::Mat::zeros(100, 100, CV_8U), cv::Mat::zeros(512, 512, CV_8U), cv::Mat::zeros(512, 512, CV_32F)});
  ASSERT_EQ(estimates.size(), 4u);
  EXPECT_NE(estimates[0].status.find("empty image"), std::string::npos);
  EXPECT_NE(estimates[1].status.find("100x100"), std::string::npos);
  EXPECT_EQ(estimates[2].status, "no_sun");
  EXPECT_NE(estimates[3].status.find("8- or 16-bit"), std::string::npos);
  for (const auto& e : estimates) EXPECT_FALSE(e.valid);
}

}  // namespace
}  // namespace dss
