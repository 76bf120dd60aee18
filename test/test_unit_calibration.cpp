// Unit calibration of a geometric-head model: the geometry of a built unit
// (height, offset, rotation, tilt, aperture positions) is recovered from its
// noise-free images with the network frozen, and its estimates come back to
// the design's accuracy; the unit model round-trips and is refused for
// another design; the spot-mismatch flag fires on the uncalibrated unit and
// stays quiet on the design and on the calibrated unit; the angle correction
// follows the unit's mask height; a spot bias keeps a unit fit of the design
// where it is.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <cstdio>
#include <functional>

#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/model/geometric_head.h"
#include "digital_sun_sensor/model/input_envelope.h"
#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/model/spot_bias.h"
#include "digital_sun_sensor/model/unit_calibration.h"
#include "digital_sun_sensor/model/unit_recalibration.h"
#include "digital_sun_sensor/sim/geometry.h"
#include "digital_sun_sensor/sim/random_mask.h"
#include "digital_sun_sensor/sim/renderer.h"
#include "digital_sun_sensor/sim/sensor_instance.h"
#include "digital_sun_sensor/train/bias_calibration.h"

namespace dss {
namespace {

// A drawn 5-aperture mask nobody tuned for.
SensorConfig drawnDesign(std::uint64_t seed) {
  RandomMaskOptions mask;
  mask.apertures = 5;
  return drawRandomMask(loadSensorConfig(std::string(DSS_SOURCE_DIR) + "/config/sensors/thesis_sa.yaml",
                                         {"detector.width_px=640", "detector.height_px=512", "detector.pitch_um=2.2",
                                          "optics.psf_node_step_deg=3", "mask.height_mm=2.5", "fov.alpha_max_deg=6",
                                          "fov.beta_max_deg=6"}),
                        mask, seed)
      .config;
}

// A built unit of the design: the mask 13 um high, offset, rotated, tilted,
// and each aperture up to a micrometre off.
SensorInstance builtUnit(const SensorConfig& design) {
  SensorInstance unit = SensorInstance::nominalOf(design);
  unit.nominal = false;
  unit.mask_offset_um = Eigen::Vector3d(7.0, -4.0, 13.0);
  unit.mask_rotation = maskRotation(0.004, 0.002, -0.0015);
  for (std::size_t k = 0; k < unit.apertures.size(); ++k) {
    unit.apertures[k].x_um += k % 2 ? 0.8 : -0.8;
    unit.apertures[k].y_um += 0.5 * (static_cast<double>(k % 3) - 1.0);
  }
  return unit;
}

TrainingSet render(const SensorInstance& instance, const InputSpec& spec, int count, std::uint64_t seed, bool noise) {
  const Renderer renderer(instance);
  Rng rng(seed);
  TrainingSet set(spec);
  RenderOptions options;
  options.noise = noise;
  for (int i = 0; i < count; ++i) {
    const double alpha = degToRad(rng.uniform(-5.5, 5.5)), beta = degToRad(rng.uniform(-5.5, 5.5));
    ImageTruth truth;
    const cv::Mat image = renderer.render(sunVectorFromAngles(alpha, beta), seed * 1000 + i, &truth, options);
    set.add(image, alpha, beta, truth.subfov_class);
  }
  return set;
}

Model untrainedModel(const SensorConfig& design) {
  ArchSpec arch = archPreset("resnet10_w16", design.numSubFovClasses());
  arch.centroid_weighting = CentroidWeighting::kValue;  // the family models' (their recipes)
  HeadOptions head;
  head.head = "geometric";
  Model model = createModel(design, arch, 1, head);
  model.net->eval();
  return model;
}

struct Errors {
  double rms_deg = 0.0;
  double flagged = 0.0;  // fraction beyond the mismatch threshold
};

Errors errorsOn(const Model& model, const TrainingSet& set) {
  std::vector<const SparseSample*> samples;
  for (const auto& s : set.samples()) samples.push_back(&s);
  const std::vector<Prediction> p = model.predictSamples(samples);
  Errors e;
  for (std::size_t i = 0; i < p.size(); ++i) {
    const double da = p[i].alpha_rad - samples[i]->alpha_rad, db = p[i].beta_rad - samples[i]->beta_rad;
    e.rms_deg += da * da + db * db;
    e.flagged += model.meta.mismatch_threshold > 0.0 && p[i].spot_mismatch > model.meta.mismatch_threshold;
  }
  e.rms_deg = radToDeg(std::sqrt(e.rms_deg / (2.0 * static_cast<double>(p.size()))));
  e.flagged /= static_cast<double>(p.size());
  return e;
}

TEST(UnitCalibration, RecoversABuiltUnitsGeometryFromItsImages) {
  const SensorConfig design = drawnDesign(41);
  const SensorInstance unit = builtUnit(design);
  Model model = untrainedModel(design);
  const TrainingSet lab = render(unit, model.meta.input, 25, 7, false);
  const TrainingSet unit_test = render(unit, model.meta.input, 20, 8, false);
  const TrainingSet design_test = render(SensorInstance::nominalOf(design), model.meta.input, 20, 8, false);
  const Errors nominal = errorsOn(model, design_test), uncalibrated = errorsOn(model, unit_test);

  const MaskGeometry before = model.net->geometry()->maskGeometry();
  recordInputEnvelope(model.meta, {1, 2});  // a family envelope that holds none of the unit's images
  const UnitCalibrationReport report = calibrateUnit(model, lab, "25 noise-free images");
  const MaskGeometry after = model.net->geometry()->maskGeometry();
  // The unit's own images widen the input envelope to hold them.
  const InputEnvelope envelope = inputEnvelopeOf(model.meta);
  EXPECT_EQ(envelope.min_sites, 1);
  for (int sites : lab.siteCounts(model.meta.input.max_sites))
    EXPECT_TRUE(envelope.contains(sites)) << sites << " lit sites";
  const Errors calibrated = errorsOn(model, unit_test);
  std::printf(
      "unit calibration: design %.6f deg on the design, %.6f on the unit; calibrated %.6f (spots %.4f -> %.4f "
      "um); height %+.2f um, offset %+.2f %+.2f um, rotation %.5f, tilt %.5f %.5f rad\n",
      nominal.rms_deg, uncalibrated.rms_deg, calibrated.rms_deg, report.spot_rms_um_before, report.spot_rms_um_after,
      after.height_um - before.height_um, after.offset_x_um, after.offset_y_um, after.rotation_rad, after.tilt_x_rad,
      after.tilt_y_rad);
  EXPECT_EQ(report.images, 25);
  EXPECT_EQ(report.images_used, 25);
  // Effective values: the per-aperture errors share a little offset and
  // rotation with the common terms (the prior splits them), and the height
  // absorbs what the network's weighting shifts with the angle.
  EXPECT_NEAR(after.height_um - before.height_um, 13.0, 2.0);
  EXPECT_NEAR(after.offset_x_um, 7.0, 0.5);
  EXPECT_NEAR(after.offset_y_um, -4.0, 0.5);
  EXPECT_NEAR(after.rotation_rad, 0.004, 5e-4);
  EXPECT_NEAR(after.tilt_x_rad, 0.002, 5e-4);
  EXPECT_NEAR(after.tilt_y_rad, -0.0015, 5e-4);
  EXPECT_GT(uncalibrated.rms_deg, 20.0 * nominal.rms_deg);
  EXPECT_LT(calibrated.rms_deg, 1.5 * nominal.rms_deg);
  EXPECT_LT(report.spot_rms_um_after, 0.1 * report.spot_rms_um_before);

  // The unit model keeps its geometry and its record, and is refused for
  // another design.
  const std::string path = ::testing::TempDir() + "/unit.dssmodel";
  saveModel(model, path);
  const Model loaded = loadModel(path, &design);
  EXPECT_DOUBLE_EQ(loaded.net->geometry()->maskGeometry().height_um, after.height_um);
  for (std::size_t k = 0; k < 2; ++k)
    EXPECT_NEAR(loaded.meta.geometry_sigma_rad[k], model.meta.geometry_sigma_rad[k],
                1e-6 * model.meta.geometry_sigma_rad[k]);
  // Each aperture's fitted position variance, which weighs its spot in the solve.
  ASSERT_EQ(model.meta.aperture_variance_um2.size(), 5u);
  EXPECT_GT(model.meta.spot_noise_um2, 0.0);
  EXPECT_EQ(loaded.meta.aperture_variance_um2, model.meta.aperture_variance_um2);
  EXPECT_EQ(loaded.net->geometry()->groupPositionVariance(), model.net->geometry()->groupPositionVariance());
  // An aperture whose spot the lab images show whole is pinned; one whose
  // spot they never show is marked unknown (the solve then hardly counts it):
  // held by the prior alone, its variance is the prior's, (20 um)^2.
  const MaskGeometry design_mask = MaskGeometry::nominalOf(design);
  int pinned = 0;
  for (int k = 0; k < 5; ++k) {
    int clearly_whole = 0, maybe_seen = 0;
    for (const auto& sample : lab.samples()) {
      const auto px = design_mask.spotPx(k, sunVectorFromAngles(sample.alpha_rad, sample.beta_rad));
      clearly_whole += px && design_mask.insideDetector(*px, 15.0);
      maybe_seen += px && design_mask.insideDetector(*px, -15.0);
    }
    const double v = model.meta.aperture_variance_um2[static_cast<std::size_t>(k)];
    std::printf("aperture %d: whole in %d of 25 lab images, position variance %.3g um2\n", k, clearly_whole, v);
    if (clearly_whole >= 3) {
      EXPECT_LT(v, 0.01) << "aperture " << k;
      ++pinned;
    }
    if (maybe_seen == 0) {
      EXPECT_NEAR(v, 400.0, 20.0) << "aperture " << k;
    }
  }
  EXPECT_GE(pinned, 3);
  EXPECT_NE(loaded.meta.unit_yaml.find("25 noise-free images"), std::string::npos) << loaded.meta.unit_yaml;
  const SensorConfig other = drawnDesign(42);
  EXPECT_THROW(loadModel(path, &other), ModelError);
  std::remove(path.c_str());
}

TEST(UnitCalibration, MismatchFlagFiresOnAnUncalibratedUnitOnly) {
  const SensorConfig design = drawnDesign(43);
  const SensorInstance unit = builtUnit(design);
  Model model = untrainedModel(design);
  const SensorInstance nominal = SensorInstance::nominalOf(design);
  const MismatchCalibration level = calibrateSpotMismatch(model, render(nominal, model.meta.input, 60, 11, true), 0);
  const Errors design_images = errorsOn(model, render(nominal, model.meta.input, 60, 12, true));
  const TrainingSet unit_images = render(unit, model.meta.input, 40, 13, true);
  const Errors uncalibrated = errorsOn(model, unit_images);
  const UnitCalibrationReport report = calibrateUnit(model, render(unit, model.meta.input, 25, 14, true), "25 images");
  const Errors calibrated = errorsOn(model, unit_images);
  std::printf("spot mismatch: level %.3g, threshold %.2f; flagged: design %.3f, unit %.3f, calibrated unit %.3f\n",
              level.level, level.threshold, design_images.flagged, uncalibrated.flagged, calibrated.flagged);
  EXPECT_LE(design_images.flagged, 0.05);
  EXPECT_GE(uncalibrated.flagged, 0.9);
  EXPECT_LE(calibrated.flagged, 0.05);

  // The geometry fitted from 25 noisy images is uncertain, and every
  // estimate's sigma carries that (in quadrature): positive, and below one
  // image's own sigma (the fit has 25 images' worth of spots).
  std::vector<const SparseSample*> samples;
  for (const auto& s : unit_images.samples()) samples.push_back(&s);
  const std::vector<Prediction> with = model.predictSamples(samples);
  const std::array<double, 2> geometry_sigma = model.meta.geometry_sigma_rad;
  EXPECT_EQ(geometry_sigma, report.geometry_sigma_rad);
  model.meta.geometry_sigma_rad = {0.0, 0.0};
  const std::vector<Prediction> without = model.predictSamples(samples);
  std::printf("geometry sigma from 25 images: %.3g / %.3g deg; image sigma %.3g / %.3g deg\n",
              radToDeg(geometry_sigma[0]), radToDeg(geometry_sigma[1]),
              radToDeg(std::sqrt(without[0].alpha_variance_rad2)), radToDeg(std::sqrt(without[0].beta_variance_rad2)));
  for (std::size_t k = 0; k < 2; ++k) {
    EXPECT_GT(geometry_sigma[k], 0.0);
    EXPECT_LT(geometry_sigma[k], std::sqrt(k ? without[0].beta_variance_rad2 : without[0].alpha_variance_rad2));
  }
  for (std::size_t i = 0; i < with.size(); ++i) {
    EXPECT_NEAR(with[i].alpha_variance_rad2, without[i].alpha_variance_rad2 + geometry_sigma[0] * geometry_sigma[0],
                1e-9 * with[i].alpha_variance_rad2);
    EXPECT_NEAR(with[i].beta_variance_rad2, without[i].beta_variance_rad2 + geometry_sigma[1] * geometry_sigma[1],
                1e-9 * with[i].beta_variance_rad2);
  }
}

// A family model used on units nobody calibrated: the tolerances' sigma is
// the size of the errors drawn units actually give (RMS over units within a
// factor 1.6 of it) and grows with the tolerances.
TEST(UnitCalibration, ToleranceSigmaIsTheErrorOfDrawnUnits) {
  const SensorConfig design = drawnDesign(45);
  const Model model = untrainedModel(design);
  const TrainingSet images = render(SensorInstance::nominalOf(design), model.meta.input, 30, 21, false);
  const std::array<double, 2> typical = unitToleranceSigma(model, images, asBuiltTolerances(1.0));
  const std::array<double, 2> twice = unitToleranceSigma(model, images, asBuiltTolerances(2.0));
  SensorConfig drawn = design;
  drawn.as_built = asBuiltTolerances(1.0);
  drawn.as_built.aperture_diameter_sigma_um = 0.0;
  double square_sum = 0.0;
  int count = 0;
  for (std::uint64_t seed = 1; seed <= 6; ++seed) {
    const TrainingSet unit_images = render(SensorInstance::draw(drawn, seed), model.meta.input, 10, 30 + seed, false);
    std::vector<const SparseSample*> samples;
    for (const auto& s : unit_images.samples()) samples.push_back(&s);
    const std::vector<Prediction> p = model.predictSamples(samples);
    for (std::size_t i = 0; i < p.size(); ++i, ++count)
      square_sum +=
          std::pow(p[i].alpha_rad - samples[i]->alpha_rad, 2) + std::pow(p[i].beta_rad - samples[i]->beta_rad, 2);
  }
  const double rms = std::sqrt(square_sum / (2.0 * count));
  const double sigma = std::sqrt(0.5 * (typical[0] * typical[0] + typical[1] * typical[1]));
  std::printf("tolerance sigma at 1x: %.3g / %.3g deg, at 2x %.3g / %.3g deg; drawn units' RMS error %.3g deg\n",
              radToDeg(typical[0]), radToDeg(typical[1]), radToDeg(twice[0]), radToDeg(twice[1]), radToDeg(rms));
  for (std::size_t k = 0; k < 2; ++k) EXPECT_NEAR(twice[k] / typical[k], 2.0, 0.2);
  EXPECT_GT(rms / sigma, 1.0 / 1.6);
  EXPECT_LT(rms / sigma, 1.6);
}

TEST(UnitCalibration, AngleCorrectionFollowsTheUnitsMaskHeight) {
  const SensorConfig design = drawnDesign(41);
  Model model = untrainedModel(design);
  // A design correction that is wrong at a mask 13 um higher:
  // the change fitted there takes it back, in proportion to the height.
  model.meta.angle_correction.degree = 1;
  model.meta.angle_correction.alpha = {2e-3, 1e-3, 0.0};
  model.meta.angle_correction.beta = {-3e-3, 0.0, 1e-3};
  SensorInstance higher = SensorInstance::nominalOf(design);
  higher.nominal = false;
  higher.mask_offset_um = Eigen::Vector3d(0.0, 0.0, 13.0);
  const TrainingSet moved = render(higher, model.meta.input, 60, 11, false);
  const BiasCalibration fit = calibrateHeightCorrection(model, moved, 13.0, 60, 2).correction;
  ASSERT_EQ(model.meta.height_corrections.size(), 1u);
  EXPECT_GE(fit.degree, 0);
  EXPECT_LT(fit.rms_alpha_after_deg, 0.2 * fit.rms_alpha_before_deg);
  EXPECT_LT(fit.rms_beta_after_deg, 0.2 * fit.rms_beta_before_deg);
  // The design's geometry and correction stay.
  EXPECT_EQ(model.heightChangeUm(), 0.0);
  EXPECT_EQ(model.meta.angle_correction.alpha[0], 2e-3);
  const auto design_bias = model.meta.angle_correction.bias(0.3, -0.2);
  EXPECT_EQ(model.angleCorrection().bias(0.3, -0.2), design_bias);
  const HeightCorrection& change = model.meta.height_corrections.front();
  EXPECT_EQ(change.height_change_um, 13.0);
  for (int axis = 0; axis < 2; ++axis)  // what the design's correction adds, taken back
    EXPECT_NEAR(change.change.bias(0.3, -0.2)[axis], -design_bias[axis], 3e-4);

  // A unit 6.5 um higher gets half the change; after a round trip through
  // the file (the design's height comes from the embedded sensor config).
  MaskGeometry unit = model.net->geometry()->maskGeometry();
  unit.height_um += 6.5;
  model.net->geometry()->setMaskGeometry(unit);
  const std::string path = ::testing::TempDir() + "/height.dssmodel";
  saveModel(model, path);
  const Model loaded = loadModel(path, &design);
  std::remove(path.c_str());
  EXPECT_NEAR(loaded.heightChangeUm(), 6.5, 1e-9);
  ASSERT_EQ(loaded.meta.height_corrections.size(), 1u);
  for (int axis = 0; axis < 2; ++axis)
    EXPECT_NEAR(loaded.angleCorrection().bias(0.3, -0.2)[axis],
                design_bias[axis] + 0.5 * change.change.bias(0.3, -0.2)[axis], 1e-12);
  // A unit lower than the design has no entry on its side: the design's.
  unit.height_um -= 13.0;
  model.net->geometry()->setMaskGeometry(unit);
  EXPECT_EQ(model.angleCorrection().bias(0.3, -0.2), design_bias);
  // Fitted on a unit's geometry it would be relative to the unit: refused.
  EXPECT_THROW(calibrateHeightCorrection(model, moved, 13.0, 60, 2), std::invalid_argument);
  // Two entries for one height are refused at load.
  model.meta.height_corrections.push_back(change);
  saveModel(model, path);
  EXPECT_THROW(loadModel(path, &design), ModelError);
  std::remove(path.c_str());

  // With a spot bias, its change at that height is fitted on the same images
  // and recorded beside the correction's; the design's bias stays.
  Model biased = untrainedModel(design);
  SpotBias bias;
  bias.degree = 0;
  bias.angle_scale_rad = biased.meta.angle_scale_rad;
  bias.group_class.assign(static_cast<std::size_t>(biased.net->geometry()->groups()), 0);
  bias.x_um = {{0.01}};
  bias.y_um = {{-0.01}};
  setSpotBias(biased, bias);
  const HeightCalibration with_bias = calibrateHeightCorrection(biased, moved, 13.0, 60, 2, /*spot_bias_degree=*/2);
  ASSERT_TRUE(with_bias.spot_bias.has_value());
  EXPECT_GT(with_bias.spot_bias->spots, 0u);
  ASSERT_EQ(biased.meta.spot_bias.by_height.size(), 1u);
  EXPECT_EQ(biased.meta.spot_bias.by_height.front().height_change_um, 13.0);
  EXPECT_EQ(biased.meta.spot_bias.by_height.front().degree, with_bias.spot_bias->bias.degree);
  EXPECT_EQ(biased.meta.spot_bias.x_um, bias.x_um);
  EXPECT_EQ(biased.net->geometry()->spotBias().x_um, bias.x_um);  // at the design's height
  // Fitted again without: the entry's bias change goes with the refit.
  calibrateHeightCorrection(biased, moved, 13.0, 60, 2);
  EXPECT_TRUE(biased.meta.spot_bias.by_height.empty());
}

TEST(UnitCalibration, HeightCorrectionsInterpolateBetweenTheirHeights) {
  AngleCorrection design;
  design.degree = 0;
  design.alpha = {1e-4};
  design.beta = {0.0};
  auto constant = [](double height_um, double value) {
    HeightCorrection h;
    h.height_change_um = height_um;
    h.change.degree = 0;
    h.change.alpha = {value};
    h.change.beta = {-value};
    return h;
  };
  const std::vector<HeightCorrection> entries = {constant(20.0, 1.5e-3), constant(10.0, 1e-3), constant(-20.0, 4e-4)};
  auto alpha_change = [&](double height_um) {
    return UnitAngleCorrection(design, entries, height_um).bias(0, 0)[0] - 1e-4;
  };
  EXPECT_DOUBLE_EQ(alpha_change(0.0), 0.0);
  EXPECT_NEAR(alpha_change(5.0), 0.5e-3, 1e-15);    // between the design and +10
  EXPECT_NEAR(alpha_change(15.0), 1.25e-3, 1e-15);  // between +10 and +20
  EXPECT_NEAR(alpha_change(30.0), 2e-3, 1e-15);     // along +10 .. +20 beyond
  EXPECT_NEAR(alpha_change(-10.0), 2e-4, 1e-15);    // the other side's own
  EXPECT_NEAR(UnitAngleCorrection(design, entries, 15.0).bias(0, 0)[1], -1.25e-3, 1e-15);
}

// The spot-bias class of each group of the head (its apertures' summed flux).
std::vector<int> groupClasses(const SensorGeometryImpl& geometry) {
  std::vector<double> flux(static_cast<std::size_t>(geometry.groups()), 0.0);
  for (int k = 0; k < geometry.apertures(); ++k)
    flux[static_cast<std::size_t>(geometry.aperture_group[k].item<std::int64_t>())] +=
        geometry.aperture_flux[k].item<double>();
  return spotBiasClasses(flux);
}

// Images of 3 x 3 clusters of sites about each group's spot through the
// model's geometry (its spot bias included) moved by offset_um(group, alpha,
// beta), whose weighted centroid is that spot, at random angles within
// +-5.5 deg (those with fewer than three whole spots left out).
std::vector<UnitImage> clusterImages(const Model& model,
                                     const std::function<Eigen::Vector2d(int, double, double)>& offset_um,
                                     std::size_t count, std::uint64_t seed, std::size_t* spot_count = nullptr) {
  const auto& geometry = *model.net->geometry();
  const double pitch = model.meta.arch.detector_pitch_um;
  Rng rng(seed);
  std::vector<UnitImage> images;
  for (std::size_t tries = 0; tries < 5 * count && images.size() < count; ++tries) {
    UnitImage image;
    image.alpha_rad = degToRad(rng.uniform(-5.5, 5.5));
    image.beta_rad = degToRad(rng.uniform(-5.5, 5.5));
    const auto spots =
        geometry.groupSpotsUm(torch::tensor({image.alpha_rad, image.beta_rad}, torch::kDouble).view({1, 2}));
    int whole = 0;
    for (int g = 0; g < geometry.groups(); ++g) {
      const Eigen::Vector2d centre = Eigen::Vector2d(spots[0][g][0].item<double>(), spots[0][g][1].item<double>()) +
                                     offset_um(g, image.alpha_rad, image.beta_rad);
      if (std::abs(centre.x()) > 0.5 * pitch * (model.meta.arch.detector_width_px - 10) ||
          std::abs(centre.y()) > 0.5 * pitch * (model.meta.arch.detector_height_px - 10))
        continue;
      ++whole;
      for (int dx = -1; dx <= 1; ++dx)
        for (int dy = -1; dy <= 1; ++dy) {
          image.site_um.push_back(centre + pitch * Eigen::Vector2d(dx, dy));
          image.site_weight.push_back(1.0 / (1.0 + dx * dx + dy * dy));
        }
    }
    if (whole < 3) continue;
    if (spot_count) *spot_count += static_cast<std::size_t>(whole);
    images.push_back(std::move(image));
  }
  return images;
}

// Spots read off their ray trace's by a bias of each aperture class (here
// as much as a tenth of a micrometre, a smooth function of the angles): the
// solve takes their mean into its angles; without a model of each class's
// departure from it, a unit fit of the design itself takes that departure
// into the apertures; with the fitted spot bias it moves nothing, and the
// solve reads the angles its corrections take to the truth.
TEST(SpotBias, IsFittedAndKeepsAUnitFitOfTheDesignWhereItIs) {
  RandomMaskOptions mask;
  mask.apertures = 5;
  mask.diameter_spread = 0.3;  // five sizes: five classes
  const SensorConfig design = drawRandomMask(drawnDesign(41), mask, 43).config;
  Model with_bias = untrainedModel(design), without = untrainedModel(design);
  const auto& geometry = *with_bias.net->geometry();
  const double scale = with_bias.meta.angle_scale_rad;
  const std::vector<int> classes = groupClasses(geometry);
  auto knownBias = [&](int g, double alpha, double beta) {
    const double c = 1.0 + classes[static_cast<std::size_t>(g)];
    const double a = alpha / scale, b = beta / scale;
    return Eigen::Vector2d(0.02 * c + 0.05 * a - 0.03 * c * a * b, -0.01 * c + 0.04 * c * b * b);
  };
  std::size_t spot_count = 0;
  const std::vector<UnitImage> images = clusterImages(with_bias, knownBias, 80, 5, &spot_count);
  ASSERT_EQ(images.size(), 80u);
  const double pitch = with_bias.meta.arch.detector_pitch_um;

  const SpotBiasFit fit = fitSpotBias(with_bias, images, 4);
  std::printf("spot bias: degree %d, %zu classes, %zu spots, RMS %.4f -> %.2g um\n", fit.bias.degree,
              fit.bias.x_um.size(), fit.spots, fit.rms_before_um, fit.rms_after_um);
  EXPECT_EQ(fit.spots, spot_count);
  EXPECT_EQ(fit.bias.x_um.size(), 5u);
  EXPECT_GT(fit.rms_before_um, 0.005);
  EXPECT_LT(fit.rms_after_um, 1e-3 * fit.rms_before_um);
  setSpotBias(with_bias, fit.bias);

  // The solve reads the angles from which the model's corrections give the
  // truth; without the bias, those less the bias's mean over the spots.
  const std::vector<Eigen::Vector2d> targets = uncorrectedAngles(with_bias, images);
  GeometricSolveOptions options;
  options.gate_um = with_bias.meta.arch.geometric_gate_um;
  options.pitch_um = pitch;
  options.width_px = with_bias.meta.arch.detector_width_px;
  options.height_px = with_bias.meta.arch.detector_height_px;
  auto solved = [&](const Model& model, const UnitImage& image) {
    std::vector<double> xy;
    for (const auto& s : image.site_um) xy.insert(xy.end(), {s.x(), s.y()});
    const auto n = static_cast<std::int64_t>(image.site_um.size());
    const auto solution =
        solveGeometry(*model.net->geometry(), torch::tensor(xy, torch::kDouble).view({n, 2}),
                      torch::tensor(image.site_weight, torch::kDouble), torch::zeros({n}, torch::kLong), 1,
                      torch::tensor({image.alpha_rad, image.beta_rad}, torch::kDouble).view({1, 2}), options);
    return Eigen::Vector2d(solution.angles_rad[0][0].item<double>(), solution.angles_rad[0][1].item<double>());
  };
  for (std::size_t i = 0; i < images.size(); i += 20) {
    EXPECT_LT((solved(with_bias, images[i]) - targets[i]).norm(), 1e-8) << "image " << i;
    EXPECT_GT((solved(without, images[i]) - targets[i]).norm(), 1e-6) << "image " << i;
  }

  // A unit fit of the design on these images: the bias known, nothing moves.
  const MaskGeometry design_mask = geometry.maskGeometry();
  auto apertureShiftRmsUm = [&](const Model& model) {
    const MaskGeometry m = model.net->geometry()->maskGeometry();
    double sum = 0.0;
    for (std::size_t k = 0; k < m.apertures_um.size(); ++k)
      sum += (m.apertures_um[k] - design_mask.apertures_um[k]).squaredNorm();
    return std::sqrt(sum / static_cast<double>(m.apertures_um.size()));
  };
  fitUnitGeometry(with_bias, images);
  fitUnitGeometry(without, images);
  std::printf("unit fit of the design: apertures moved %.2g um RMS with the spot bias, %.4f um without\n",
              apertureShiftRmsUm(with_bias), apertureShiftRmsUm(without));
  EXPECT_LT(apertureShiftRmsUm(with_bias), 1e-4);
  EXPECT_GT(apertureShiftRmsUm(without), 0.005);

  // The model file keeps it; a bias for another head is refused.
  const std::string path = ::testing::TempDir() + "/spot_bias.dssmodel";
  saveModel(with_bias, path);
  const Model loaded = loadModel(path, &design);
  EXPECT_EQ(loaded.meta.spot_bias.degree, fit.bias.degree);
  EXPECT_EQ(loaded.meta.spot_bias.group_class, fit.bias.group_class);
  EXPECT_EQ(loaded.meta.spot_bias.x_um, fit.bias.x_um);
  EXPECT_EQ(loaded.net->geometry()->spotBias().y_um, fit.bias.y_um);
  std::remove(path.c_str());
  SpotBias wrong = fit.bias;
  wrong.group_class.push_back(0);
  EXPECT_THROW(setSpotBias(with_bias, wrong), std::invalid_argument);
}

// The bias changes with the mask height (an air gap spreads the spots at
// wide angles otherwise): its change is fitted at a moved height against the
// design's bias, interpolated in the height, follows the geometry and the
// file, and a unit fit of a unit at that height moves no aperture for it.
TEST(SpotBias, FollowsTheMaskHeight) {
  RandomMaskOptions mask;
  mask.apertures = 5;
  mask.diameter_spread = 0.3;
  const SensorConfig design = drawRandomMask(drawnDesign(41), mask, 43).config;
  Model model = untrainedModel(design);
  auto& geometry = *model.net->geometry();
  const double scale = model.meta.angle_scale_rad;
  const std::vector<int> classes = groupClasses(geometry);
  auto designBias = [&](int g, double alpha, double beta) {
    const double c = 1.0 + classes[static_cast<std::size_t>(g)];
    return Eigen::Vector2d(0.02 * c + 0.05 * alpha / scale, -0.01 * c * beta / scale);
  };
  auto changeAt10um = [&](int g, double alpha, double beta) {
    const double c = 1.0 + classes[static_cast<std::size_t>(g)];
    const double a = alpha / scale, b = beta / scale;
    return Eigen::Vector2d(0.03 * c * a * a, -0.02 * c * a * b);
  };
  setSpotBias(model, fitSpotBias(model, clusterImages(model, designBias, 60, 7), 3).bias);
  const SpotBias design_bias = model.meta.spot_bias;
  const MaskGeometry design_mask = geometry.maskGeometry();
  MaskGeometry higher = design_mask;
  higher.height_um += 10.0;

  // Fitted at +10 um: the change alone (the design's bias is in the readings).
  geometry.setMaskGeometry(higher);
  const std::vector<UnitImage> images = clusterImages(model, changeAt10um, 60, 8);
  const SpotBiasFit change = fitSpotBias(model, images, 3, /*change_from_model_bias=*/true);
  std::printf("spot bias change at +10 um: degree %d, RMS %.4f -> %.2g um\n", change.bias.degree, change.rms_before_um,
              change.rms_after_um);
  EXPECT_GT(change.rms_before_um, 0.005);
  EXPECT_GE(change.bias.degree, 2);
  EXPECT_LT(change.rms_after_um, 1e-3 * change.rms_before_um);
  SpotBias bias = design_bias;
  bias.by_height.push_back({10.0, change.bias.degree, change.bias.x_um, change.bias.y_um});
  bias.by_height.push_back({-10.0, AngleCorrection::kNone, {}, {}});  // fitted, and no change below
  setSpotBias(model, bias);

  // Interpolated in the height; the geometry adds the bias at its own.
  const Eigen::Vector2d angles(degToRad(3.0), degToRad(-2.0));
  auto groupBias = [&](const SpotBias& b, int g) {
    std::vector<Eigen::Vector2d> spots(static_cast<std::size_t>(geometry.groups()), Eigen::Vector2d::Zero());
    b.addTo(angles, spots);
    return spots[static_cast<std::size_t>(g)];
  };
  for (int g = 0; g < geometry.groups(); ++g) {
    const Eigen::Vector2d d = groupBias(design_bias, g), c = groupBias(change.bias, g);
    EXPECT_LT((groupBias(bias.at(5.0), g) - (d + 0.5 * c)).norm(), 1e-12);
    EXPECT_LT((groupBias(bias.at(20.0), g) - (d + 2.0 * c)).norm(), 1e-12);
    EXPECT_LT((groupBias(bias.at(-5.0), g) - d).norm(), 1e-12);
    EXPECT_LT((groupBias(geometry.spotBias(), g) - (d + c)).norm(), 1e-12);
  }
  EXPECT_TRUE(geometry.spotBias().by_height.empty());

  // A unit at +10 um, fitted from the design: its height found, its
  // apertures left where they are (without the change they move).
  auto apertureShiftRmsUm = [&](const MaskGeometry& m) {
    double sum = 0.0;
    for (std::size_t k = 0; k < m.apertures_um.size(); ++k)
      sum += (m.apertures_um[k] - design_mask.apertures_um[k]).squaredNorm();
    return std::sqrt(sum / static_cast<double>(m.apertures_um.size()));
  };
  const std::vector<UnitImage> unit_images = clusterImages(
      model, [](int, double, double) { return Eigen::Vector2d(0, 0); }, 80, 9);
  auto fitFromDesign = [&](const SpotBias& b) {
    Model unit = untrainedModel(design);
    setSpotBias(unit, b);
    fitUnitGeometry(unit, unit_images);
    return unit.net->geometry()->maskGeometry();
  };
  const MaskGeometry with_change = fitFromDesign(bias), without_change = fitFromDesign(design_bias);
  std::printf("unit at +10 um: height %.3f um, apertures moved %.2g um with the change; %.3f um, %.4f um without\n",
              with_change.height_um - design_mask.height_um, apertureShiftRmsUm(with_change),
              without_change.height_um - design_mask.height_um, apertureShiftRmsUm(without_change));
  EXPECT_NEAR(with_change.height_um - design_mask.height_um, 10.0, 0.05);
  EXPECT_LT(apertureShiftRmsUm(with_change), 0.2 * apertureShiftRmsUm(without_change));

  // The file keeps the changes; one height twice is refused.
  const std::string path = ::testing::TempDir() + "/spot_bias_height.dssmodel";
  saveModel(model, path);
  const Model loaded = loadModel(path, &design);
  std::remove(path.c_str());
  ASSERT_EQ(loaded.meta.spot_bias.by_height.size(), 2u);
  EXPECT_EQ(loaded.meta.spot_bias.by_height[0].x_um, change.bias.x_um);
  EXPECT_EQ(loaded.meta.spot_bias.by_height[1].degree, AngleCorrection::kNone);
  for (int g = 0; g < geometry.groups(); ++g)
    EXPECT_LT((groupBias(loaded.net->geometry()->spotBias(), g) - groupBias(geometry.spotBias(), g)).norm(), 1e-12);
  SpotBias twice = bias;
  twice.by_height.push_back(twice.by_height.front());
  EXPECT_THROW(setSpotBias(model, twice), std::invalid_argument);
}

TEST(UnitCalibration, RefusesAModelWithoutAGeometricHead) {
  const SensorConfig design = drawnDesign(41);
  HeadOptions head;
  head.head = "classic";
  Model model = createModel(design, archPreset("resnet10_w16", design.numSubFovClasses()), 1, head);
  const TrainingSet lab = render(SensorInstance::nominalOf(design), model.meta.input, 3, 1, false);
  try {
    calibrateUnit(model, lab, "3 images");
    FAIL() << "a classic head was calibrated";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("not geometric"), std::string::npos) << e.what();
  }
}

// The in-flight window: far references refused, memory bounded, no refit
// before enough pairs spread over the field.
TEST(UnitCalibration, RecalibratorGatesItsReferences) {
  RecalibrationOptions options;
  options.window = 40;
  options.min_pairs = 20;
  options.refit_every = 10;
  options.min_spread_deg = 1.0;
  UnitRecalibrator recalibrator(options);
  UnitImage image;
  image.site_um = {Eigen::Vector2d(1.0, 2.0)};
  image.site_weight = {1.0};
  // A reference 3 deg from the estimate is refused.
  image.alpha_rad = degToRad(3.0);
  EXPECT_FALSE(recalibrator.add(image, 0.0, 0.0));
  EXPECT_EQ(recalibrator.refused(), 1u);
  // 30 references at one point: enough pairs, no spread.
  image.alpha_rad = image.beta_rad = degToRad(0.5);
  for (int i = 0; i < 30; ++i) EXPECT_TRUE(recalibrator.add(image, image.alpha_rad, image.beta_rad));
  EXPECT_FALSE(recalibrator.due());
  // Spread over +-3 deg: due; the window keeps the newest 40.
  Rng rng(3);
  for (int i = 0; i < 30; ++i) {
    image.alpha_rad = degToRad(rng.uniform(-3.0, 3.0));
    image.beta_rad = degToRad(rng.uniform(-3.0, 3.0));
    recalibrator.add(image, image.alpha_rad, image.beta_rad);
  }
  EXPECT_EQ(recalibrator.pairs(), 40u);
  EXPECT_GT(recalibrator.spreadDeg(), 1.0);
  EXPECT_TRUE(recalibrator.due());
  options.min_pairs = 50;
  EXPECT_THROW(UnitRecalibrator{options}, std::invalid_argument);  // more than the window
}

}  // namespace
}  // namespace dss
