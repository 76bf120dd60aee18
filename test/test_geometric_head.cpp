// The geometric head's trace and solve: the trace equals the baseline's
// calibration model, the solve recovers known angles exactly from noise-free
// spots (spots leaving the detector, cut by its edge, overlapping, stray
// sites), and its gradients match finite differences.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>

#include "digital_sun_sensor/baseline/calibration_model.h"
#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/model/geometric_head.h"
#include "digital_sun_sensor/model/geometry_design.h"
#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/model/physics_prior.h"
#include "digital_sun_sensor/model/sparse_input.h"
#include "digital_sun_sensor/model/sscnn_estimator.h"
#include "digital_sun_sensor/sim/dataset_generator.h"
#include "digital_sun_sensor/sim/geometry.h"
#include "digital_sun_sensor/sim/random_mask.h"
#include "digital_sun_sensor/sim/renderer.h"
#include "digital_sun_sensor/sim/sensor_instance.h"
#include "gradcheck.h"

namespace dss {
namespace {

// A drawn irregular mask on a non-square detector with a cover glass, and a
// unit of it with offset, rotation and tilt (the baseline's model of it).
struct Fixture {
  SensorConfig config;
  MaskGeometry unit;
  SensorGeometry geometry{nullptr};
};

Fixture makeFixture(int apertures, std::uint64_t seed) {
  SensorConfig base = loadSensorConfig(
      DSS_SOURCE_DIR "/config/sensors/thesis_sa.yaml",
      {"detector.width_px=640", "detector.height_px=512", "detector.pitch_um=2.2", "mask.height_mm=2.5",
       "fov.alpha_max_deg=8", "fov.beta_max_deg=8", "cover_glass.enabled=true", "cover_glass.thickness_mm=0.4"});
  RandomMaskOptions options;
  options.apertures = apertures;
  Fixture f;
  f.config = drawRandomMask(base, options, seed).config;
  f.unit = MaskGeometry::nominalOf(f.config);
  f.unit.height_um += 13.0;
  f.unit.offset_x_um = 7.0;
  f.unit.offset_y_um = -4.0;
  f.unit.rotation_rad = 0.004;
  f.unit.tilt_x_rad = 0.002;
  f.unit.tilt_y_rad = -0.0015;
  f.geometry = SensorGeometry(apertures, apertures);
  GeometryDesign design;
  design.height_um = f.unit.height_um;
  for (const auto& a : f.unit.apertures_um) design.apertures_um.push_back({a.x(), a.y()});
  design.glass_thickness_um = f.unit.glass_thickness_um;
  design.glass_index = f.unit.glass_index;
  f.geometry->setDesign(design);
  torch::NoGradGuard no_grad;
  f.geometry->offset_um[0] = f.unit.offset_x_um;
  f.geometry->offset_um[1] = f.unit.offset_y_um;
  f.geometry->rotation_rad[0] = f.unit.rotation_rad;
  f.geometry->tilt_rad[0] = f.unit.tilt_x_rad;
  f.geometry->tilt_rad[1] = f.unit.tilt_y_rad;
  return f;
}

TEST(GeometricHead, TraceEqualsTheBaselinesCalibrationModel) {
  const Fixture f = makeFixture(6, 41);
  Rng rng(3);
  for (int trial = 0; trial < 20; ++trial) {
    const double alpha = degToRad(rng.uniform(-8, 8)), beta = degToRad(rng.uniform(-8, 8));
    const auto spots = f.geometry->spotsUm(torch::tensor({alpha, beta}, torch::kFloat64).view({1, 2}));
    for (int k = 0; k < f.unit.numApertures(); ++k) {
      const auto expected = f.unit.spotPx(k, sunVectorFromAngles(alpha, beta));
      ASSERT_TRUE(expected);
      EXPECT_NEAR(spots[0][k][0].item<double>(), expected->x() * f.unit.pitch_um, 1e-9);
      EXPECT_NEAR(spots[0][k][1].item<double>(), expected->y() * f.unit.pitch_um, 1e-9);
    }
  }
}

// The head's height is the mask's mid-plane, half its thickness above the
// exit face. A unit whose mask sits lower in its glass window (wide_ma: a
// 0.2 um mask on a 0.5 mm window; a unit 15 um lower) keeps that half
// thickness in air, as the simulator does: the head's spots and the plain
// solve's move as the simulator's chief rays. (The glass had taken it:
// 0.14 um off at 65 deg from the axis, and a calibrated unit, noise-free,
// was read 0.0019 deg off against 0.00055.)
TEST(GeometricHead, LoweredMaskKeepsItsHalfThicknessInAir) {
  const SensorConfig config = loadSensorConfig(DSS_SOURCE_DIR "/config/sensors/wide_ma.yaml");
  HeadOptions head;
  head.head = "geometric";
  const Model model = createModel(config, archPreset("resnet10_w16", config.numSubFovClasses()), 1, head);
  SensorGeometryImpl& geometry = *model.net->geometry();
  const MaskGeometry nominal = geometry.maskGeometry();
  MaskGeometry lowered = nominal;
  lowered.height_um -= 15.0;
  const SensorInstance design = SensorInstance::nominalOf(config);
  SensorInstance unit = design;
  unit.mask_offset_um.z() = -15.0;
  const GlassSlab glass{config.cover_glass.thickness_mm * 1000.0, config.cover_glass.refractive_index};
  for (const auto& [alpha_deg, beta_deg] : std::vector<std::pair<double, double>>{{56.5, -57.7}, {10.0, 5.0}}) {
    const auto angles = torch::tensor({degToRad(alpha_deg), degToRad(beta_deg)}, torch::kFloat64).view({1, 2});
    const Eigen::Vector3d sun = sunVectorFromAngles(degToRad(alpha_deg), degToRad(beta_deg));
    geometry.setMaskGeometry(nominal);
    const auto before = geometry.spotsUm(angles);
    geometry.setMaskGeometry(lowered);
    const auto after = geometry.spotsUm(angles);
    for (int k : {0, 24, 48}) {
      const Eigen::Vector2d simulated = *traceToDetector(unit.apertureCentreUm(k), sun, glass) -
                                        *traceToDetector(design.apertureCentreUm(k), sun, glass);
      const Eigen::Vector2d plain = *lowered.spotPx(k, sun) - *nominal.spotPx(k, sun);  // pitch 1: um
      for (int axis = 0; axis < 2; ++axis) {
        EXPECT_NEAR((after[0][k][axis] - before[0][k][axis]).item<double>(), simulated[axis], 1e-6) << k;
        EXPECT_NEAR(plain[axis], simulated[axis], 1e-6) << k;
      }
    }
  }
}

// Noise-free sites of the spots the detector sees: each spot a pattern
// symmetric about its centre (so its centroid is the centre), clipped by
// the detector; a clipped spot gets a site on the outermost column or row.
struct Sites {
  std::vector<double> xy_um, weight;
  std::vector<std::int64_t> index;
  void add(double x, double y, double w, std::int64_t image) {
    xy_um.insert(xy_um.end(), {x, y});
    weight.push_back(w);
    index.push_back(image);
  }
};

void addSpot(Sites& sites, const Eigen::Vector2d& centre_um, double scale, const SensorConfig& config,
             std::int64_t image) {
  const double half_x = 0.5 * config.detector.width_px * config.detector.pitch_um;
  const double half_y = 0.5 * config.detector.height_px * config.detector.pitch_um;
  bool clipped = false, any = false;
  for (int i = -4; i <= 4; ++i)
    for (int j = -4; j <= 4; ++j) {
      const double dx = 2.1 * i + 0.3 * j, dy = 1.9 * j - 0.2 * i;  // sheared: no grid alignment
      const double x = centre_um.x() + dx, y = centre_um.y() + dy;
      if (std::abs(x) > half_x || std::abs(y) > half_y) {
        clipped = true;
        continue;
      }
      any = true;
      sites.add(x, y, scale * std::exp(-(dx * dx + dy * dy) / 40.0), image);
    }
  if (clipped && any) {
    const double x = std::clamp(centre_um.x(), -half_x + 0.2, half_x - 0.2);
    const double y = std::clamp(centre_um.y(), -half_y + 0.2, half_y - 0.2);
    sites.add(std::abs(centre_um.x()) > half_x - 10 ? std::copysign(half_x - 0.5, x) : x,
              std::abs(centre_um.x()) > half_x - 10 ? y : std::copysign(half_y - 0.5, y), 0.01, image);
  }
}

GeometricSolveOptions optionsFor(const SensorConfig& config) {
  GeometricSolveOptions o;
  o.gate_um = 120.0;
  o.pitch_um = config.detector.pitch_um;
  o.width_px = config.detector.width_px;
  o.height_px = config.detector.height_px;
  return o;
}

torch::Tensor tensorOf(const std::vector<double>& v) { return torch::tensor(v, torch::kFloat64); }

TEST(GeometricHead, SolveRecoversKnownAnglesExactlyOnAnyMask) {
  for (const int apertures : {3, 7, 12}) {
    const Fixture f = makeFixture(apertures, 100 + apertures);
    Rng rng(apertures);
    Sites sites;
    std::vector<double> truth, reference;
    int cut_spots = 0, images = 0;
    for (; images < 12; ++images) {
      const double alpha = degToRad(rng.uniform(-8, 8)), beta = degToRad(rng.uniform(-8, 8));
      truth.insert(truth.end(), {alpha, beta});
      // The reference (a coarse estimate) 0.3 deg off.
      reference.insert(reference.end(), {alpha + degToRad(0.3), beta - degToRad(0.2)});
      std::vector<Eigen::Vector2d> spots_um;
      for (int k = 0; k < f.unit.numApertures(); ++k) {
        const auto px = f.unit.spotPx(k, sunVectorFromAngles(alpha, beta));
        spots_um.push_back(*px * f.unit.pitch_um);
        if (!f.unit.insideDetector(*px, 4.5 * 2.2 / f.unit.pitch_um) && f.unit.insideDetector(*px, -9.0)) ++cut_spots;
        addSpot(sites, spots_um.back(), 1.0 + 0.5 * k, f.config, images);
      }
      // A bright stray site beyond the gate of every spot.
      for (int attempt = 0; attempt < 100; ++attempt) {
        const Eigen::Vector2d stray(rng.uniform(-700, 700), rng.uniform(-560, 560));
        if (std::all_of(spots_um.begin(), spots_um.end(), [&](const auto& s) { return (s - stray).norm() > 150; })) {
          sites.add(stray.x(), stray.y(), 3.0, images);
          break;
        }
      }
    }
    const auto solution =
        solveGeometry(*f.geometry, tensorOf(sites.xy_um).view({-1, 2}), tensorOf(sites.weight),
                      torch::tensor(sites.index), images, tensorOf(reference).view({-1, 2}), optionsFor(f.config));
    const auto error = (solution.angles_rad - tensorOf(truth).view({-1, 2})).abs().max().item<double>();
    EXPECT_LT(error, 1e-10) << apertures << " apertures";
    EXPECT_LT(solution.residual_um.max().item<double>(), 1e-6);
    EXPECT_GE(solution.spots_read.min().item<double>(), 1.0);
    EXPECT_GT(cut_spots, 0) << "the draw should cut some spots";
  }
}

// A full 3 x 3 lattice (thesis_ma) looks the same one pitch (3 deg) further
// once a row or column has left the detector, but for the spots that shift
// would put on it: with a coarse estimate that knows nothing (normal
// incidence), the search still finds the true association everywhere.
TEST(GeometricHead, PeriodicLatticeIsNotReadOnePitchOff) {
  const SensorConfig config = loadSensorConfig(DSS_SOURCE_DIR "/config/sensors/thesis_ma.yaml");
  const GeometryDesign design = geometryDesignOf(config);
  SensorGeometry geometry(static_cast<int>(design.apertures_um.size()), design.groupCount());
  geometry->setDesign(design);
  Rng rng(5);
  Sites sites;
  std::vector<double> truth;
  int images = 0, edge_left = 0;
  const double half_um = 0.5 * config.detector.width_px * config.detector.pitch_um;
  for (; images < 60; ++images) {
    const double alpha = degToRad(rng.uniform(-4.5, 4.5)), beta = degToRad(rng.uniform(-4.5, 4.5));
    truth.insert(truth.end(), {alpha, beta});
    const auto spots = geometry->spotsUm(torch::tensor({alpha, beta}, torch::kFloat64).view({1, 2}));
    int off = 0;
    for (int k = 0; k < spots.size(1); ++k) {
      const Eigen::Vector2d centre(spots[0][k][0].item<double>(), spots[0][k][1].item<double>());
      off += std::abs(centre.x()) > half_um + 10.0 || std::abs(centre.y()) > half_um + 10.0;
      addSpot(sites, centre, 1.0, config, images);
    }
    edge_left += off > 0;
  }
  const std::vector<double> coarse(truth.size(), 0.0);
  auto options = optionsFor(config);
  options.gate_um = geometricGateUm(config, design);
  options.search_reference = true;
  const auto solution = solveGeometry(*geometry, tensorOf(sites.xy_um).view({-1, 2}), tensorOf(sites.weight),
                                      torch::tensor(sites.index), images, tensorOf(coarse).view({-1, 2}), options);
  const auto error = (solution.angles_rad - tensorOf(truth).view({-1, 2})).abs().max().item<double>();
  EXPECT_LT(error, 1e-10);
  EXPECT_GT(edge_left, 20) << "most draws should have a row or column off the detector";
}

// One aperture (thesis_sa: 512 x 512 px of 1.55 um, 5 mm, the light above
// 90 % of the peak): a spot whose centre lies within its radius of the
// detector's edge is cut, and its plain centroid is pulled inward by up to
// a third of the radius. The solve reads its centre along the cut from the
// shape of its light instead, along an edge and in a corner.
TEST(GeometricHead, SpotCutByTheEdgeIsReadAtItsCentre) {
  const SensorConfig config = loadSensorConfig(DSS_SOURCE_DIR "/config/sensors/thesis_sa.yaml");
  const GeometryDesign design = geometryDesignOf(config);
  SensorGeometry geometry(1, 1);
  geometry->setDesign(design);
  const double pitch = config.detector.pitch_um, half = 0.5 * config.detector.width_px * pitch;
  // The top tenth of a Gaussian spot (not a quadratic), 12 um in radius,
  // integrated over each pixel (4 x 4 samples).
  constexpr double kRadiusUm = 12.0, kThreshold = 0.9;
  const double sigma2 = kRadiusUm * kRadiusUm / (2.0 * std::log(1.0 / kThreshold));
  auto addCap = [&](Sites& sites, const Eigen::Vector2d& centre, std::int64_t image) {
    const int lo_x = static_cast<int>(std::floor((centre.x() - kRadiusUm + half) / pitch)) - 1;
    const int lo_y = static_cast<int>(std::floor((centre.y() - kRadiusUm + half) / pitch)) - 1;
    const int span = static_cast<int>(2.0 * kRadiusUm / pitch) + 3;
    for (int i = lo_x; i <= lo_x + span; ++i)
      for (int j = lo_y; j <= lo_y + span; ++j) {
        if (i < 0 || j < 0 || i >= config.detector.width_px || j >= config.detector.height_px) continue;
        const double x = (i + 0.5) * pitch - half, y = (j + 0.5) * pitch - half;
        double w = 0.0;
        for (int u = 0; u < 4; ++u)
          for (int v = 0; v < 4; ++v) {
            const Eigen::Vector2d at(x + (u - 1.5) * pitch / 4.0, y + (v - 1.5) * pitch / 4.0);
            w += std::max(0.0, std::exp(-(at - centre).squaredNorm() / (2.0 * sigma2)) - kThreshold) / 16.0;
          }
        if (w > 0.0) sites.add(x, y, w, image);
      }
  };
  Rng rng(9);
  Sites sites;
  std::vector<Eigen::Vector2d> centres;
  // Distances of the centre from the right edge (um); the last two images in
  // the top right corner.
  const std::vector<double> inside_um = {0.4, 1.0, 2.0, 3.3, 5.0, 7.5, 10.0, 30.0, 2.5, 6.0};
  for (std::size_t image = 0; image < inside_um.size(); ++image) {
    const bool corner = image >= 8;
    const Eigen::Vector2d centre(half - inside_um[image],
                                 corner ? half - 0.7 * inside_um[image] : rng.uniform(-300, 300));
    centres.push_back(centre);
    addCap(sites, centre, static_cast<std::int64_t>(image));
  }
  const auto images = static_cast<std::int64_t>(centres.size());
  std::vector<double> reference;
  for (const auto& c : centres) {
    // A coarse estimate 0.03 deg off (the spot moves against the sun).
    reference.insert(reference.end(),
                     {std::atan(-c.x() / design.height_um) + 5e-4, std::atan(-c.y() / design.height_um)});
  }
  auto options = optionsFor(config);
  const auto solution = solveGeometry(*geometry, tensorOf(sites.xy_um).view({-1, 2}), tensorOf(sites.weight),
                                      torch::tensor(sites.index), images, tensorOf(reference).view({-1, 2}), options);
  const auto spots = geometry->spotsUm(solution.angles_rad);
  double worst_plain_um = 0.0;
  for (std::int64_t b = 0; b < images; ++b) {
    const Eigen::Vector2d read(spots[b][0][0].item<double>(), spots[b][0][1].item<double>());
    const auto& truth = centres[static_cast<std::size_t>(b)];
    // Along an edge within 0.1 um (0.001 deg at 5 mm), in a corner 0.3 um.
    EXPECT_LT((read - truth).norm(), b >= 8 ? 0.3 : 0.1)
        << "centre " << inside_um[static_cast<std::size_t>(b)] << " um inside the edge";
    // The plain centroid of the same sites.
    Eigen::Vector2d plain = Eigen::Vector2d::Zero();
    double sum = 0.0;
    for (std::size_t i = 0; i < sites.weight.size(); ++i)
      if (sites.index[i] == b) {
        plain += sites.weight[i] * Eigen::Vector2d(sites.xy_um[2 * i], sites.xy_um[2 * i + 1]);
        sum += sites.weight[i];
      }
    worst_plain_um = std::max(worst_plain_um, (plain / sum - truth).norm());
  }
  EXPECT_GT(worst_plain_um, 3.0) << "the cut should pull the plain centroid inward";
}

// Spots on the pixel grid as the detector shows them: a disk of 6 px whose
// edge falls off over ~2 px (peak 1), plus a glow of stray light rising
// across it (glow * (1 + x / 10 px)), cut at 0.2 and rescaled (the on-chip
// threshold). The symmetric read-out (ArchSpec::geometric_symmetric_spots)
// finds the centres of the clean spots as the centroid does; with a glow of
// 0.15, lit beside the spot on one side only, which drags the centroid
// toward it, it is dragged less (worst image 5.1e-4 against 7.6e-4 rad).
TEST(GeometricHead, SymmetricSpotsAreReadAtTheirCentres) {
  const Fixture f = makeFixture(7, 107);
  const double pitch = f.config.detector.pitch_um;
  const double cx = 0.5 * (f.config.detector.width_px - 1), cy = 0.5 * (f.config.detector.height_px - 1);
  auto addGridSpot = [&](Sites& sites, const Eigen::Vector2d& centre_px, double glow, std::int64_t image) {
    for (int i = static_cast<int>(centre_px.x()) - 10; i <= static_cast<int>(centre_px.x()) + 10; ++i)
      for (int j = static_cast<int>(centre_px.y()) - 10; j <= static_cast<int>(centre_px.y()) + 10; ++j) {
        double v = 0.0;
        for (int u = 0; u < 4; ++u)
          for (int w = 0; w < 4; ++w) {
            const Eigen::Vector2d at(i + (u - 1.5) / 4.0, j + (w - 1.5) / 4.0);
            v += 1.0 / (1.0 + std::exp(2.0 * ((at - centre_px).norm() - 6.0))) / 16.0;
          }
        v = std::max(0.0, v + glow * (1.0 + (i - centre_px.x()) / 10.0) - 0.2) / 0.8;
        if (v > 0.0) sites.add((i - cx) * pitch, (j - cy) * pitch, v, image);
      }
  };
  Rng rng(17);
  std::vector<double> truth, reference;
  Sites clean, glowing;
  std::int64_t images = 0;
  for (; images < 12; ++images) {
    const double alpha = degToRad(rng.uniform(-6, 6)), beta = degToRad(rng.uniform(-6, 6));
    truth.insert(truth.end(), {alpha, beta});
    reference.insert(reference.end(), {alpha + degToRad(0.05), beta - degToRad(0.05)});
    for (int k = 0; k < f.unit.numApertures(); ++k) {
      const auto spot = f.unit.spotPx(k, sunVectorFromAngles(alpha, beta));  // from the detector centre
      if (!spot || !f.unit.insideDetector(*spot, 12.0)) continue;
      const Eigen::Vector2d centre_px(spot->x() + cx, spot->y() + cy);
      addGridSpot(clean, centre_px, 0.0, images);
      addGridSpot(glowing, centre_px, 0.15, images);
    }
  }
  auto worstError = [&](const Sites& sites, bool symmetric) {
    auto options = optionsFor(f.config);
    options.symmetric_spots = symmetric;
    const auto solution = solveGeometry(*f.geometry, tensorOf(sites.xy_um).view({-1, 2}), tensorOf(sites.weight),
                                        torch::tensor(sites.index), images, tensorOf(reference).view({-1, 2}), options);
    return (solution.angles_rad - tensorOf(truth).view({-1, 2})).abs().max().item<double>();
  };
  // A pixel is 2.2 um / 2.5 mm = 8.8e-4 rad; 2e-5 rad is 0.02 px.
  EXPECT_LT(worstError(clean, true), 2e-5);
  EXPECT_LT(worstError(clean, false), 2e-5);
  const double centroid = worstError(glowing, false), symmetric = worstError(glowing, true);
  EXPECT_GT(centroid, 1e-4) << "the glow should drag the centroid";
  EXPECT_LT(symmetric, 0.8 * centroid);
}

// Three apertures of different sizes (docs/results/irregular_masks.md, mask
// D): the relative threshold may leave one spot lit, and nothing in the
// image says which aperture made it; the solve says so. With apertures alike
// a dark spot where the geometry puts one rules a hypothesis out, and with
// two spots lit the association is known.
TEST(GeometricHead, LoneSpotOfAperturesOfDifferentSizesIsAmbiguous) {
  const SensorConfig base = loadSensorConfig(
      DSS_SOURCE_DIR "/config/sensors/thesis_sa.yaml",
      {"detector.width_px=640", "detector.height_px=480", "detector.pitch_um=3.0", "mask.height_mm=3.0",
       "threshold.level_fraction=0.7", "fov.alpha_max_deg=9", "fov.beta_max_deg=9"});
  RandomMaskOptions mask;
  mask.apertures = 3;
  mask.diameter_um = 110.0;
  for (const double spread : {0.3, 0.0}) {
    mask.diameter_spread = spread;
    const SensorConfig config = drawRandomMask(base, mask, 41).config;
    const GeometryDesign design = geometryDesignOf(config);
    SensorGeometry geometry(static_cast<int>(design.apertures_um.size()), design.groupCount());
    geometry->setDesign(design);
    const double alpha = degToRad(6.647), beta = degToRad(-0.213);
    const auto spots = geometry->spotsUm(torch::tensor({alpha, beta}, torch::kFloat64).view({1, 2}));
    const double half_w = 0.5 * 640 * 3.0 - 100.0, half_h = 0.5 * 480 * 3.0 - 100.0;
    Sites sites;
    int whole = 0;
    for (int k = 0; k < spots.size(1); ++k) {
      const Eigen::Vector2d centre(spots[0][k][0].item<double>(), spots[0][k][1].item<double>());
      if (std::abs(centre.x()) > half_w || std::abs(centre.y()) > half_h) continue;
      if (whole++ == 0) addSpot(sites, centre, 1.0, config, 0);  // image 0: the first whole spot alone
      addSpot(sites, centre, 1.0, config, 1);                    // image 1: every whole spot
    }
    ASSERT_GE(whole, 2) << "spread " << spread;
    auto options = optionsFor(config);
    options.gate_um = geometricGateUm(config, design);
    options.search_reference = true;
    const auto solution = solveGeometry(*geometry, tensorOf(sites.xy_um).view({-1, 2}), tensorOf(sites.weight),
                                        torch::tensor(sites.index), 2, torch::zeros({2, 2}, torch::kFloat64), options);
    EXPECT_EQ(solution.lone_spot_ambiguous[0].item<bool>(), spread > 0.0) << "spread " << spread;
    EXPECT_FALSE(solution.lone_spot_ambiguous[1].item<bool>()) << "spread " << spread;
    EXPECT_NEAR(solution.angles_rad[1][0].item<double>(), alpha, 1e-9);
    EXPECT_NEAR(solution.angles_rad[1][1].item<double>(), beta, 1e-9);
  }
}

TEST(GeometricHead, OverlappingSpotsReadAsOneGroup) {
  // Two apertures 30 um apart (their spots merge) and one apart: grouped,
  // the merged light's centroid is the flux-weighted mean of its members'.
  SensorGeometry geometry(3, 2);
  GeometryDesign design;
  design.height_um = 2500.0;
  design.apertures_um = {{-100.0, 20.0}, {-70.0, 20.0}, {300.0, -150.0}};
  design.groups = {0, 0, 1};
  design.fluxes = {1.0, 2.0, 1.5};
  geometry->setDesign(design);
  SensorConfig config;
  config.detector = {640, 512, 2.2};
  const double alpha = degToRad(2.5), beta = degToRad(-1.0);
  const auto spots = geometry->spotsUm(torch::tensor({alpha, beta}, torch::kFloat64).view({1, 2}));
  Sites sites;
  for (int k = 0; k < 3; ++k)
    addSpot(sites, {spots[0][k][0].item<double>(), spots[0][k][1].item<double>()}, design.fluxes[k], config, 0);
  auto options = optionsFor(config);
  const auto solution =
      solveGeometry(*geometry, tensorOf(sites.xy_um).view({-1, 2}), tensorOf(sites.weight), torch::tensor(sites.index),
                    1, torch::tensor({alpha - 0.004, beta + 0.003}, torch::kFloat64).view({1, 2}), options);
  EXPECT_NEAR(solution.angles_rad[0][0].item<double>(), alpha, 1e-10);
  EXPECT_NEAR(solution.angles_rad[0][1].item<double>(), beta, 1e-10);
  EXPECT_EQ(solution.spots_read[0].item<double>(), 2.0);
}

TEST(GeometricHead, AnUncertainApertureCountsForWhatIsKnownOfIt) {
  // One aperture of the unit 1.5 um from where the geometry has it: solved
  // with every position exact, its spot pulls the angles and the residual
  // up; with its position variance set (as a unit calibration that did not
  // pin it would), the others decide and the residual falls to theirs.
  Fixture f = makeFixture(6, 61);
  const double alpha = degToRad(1.5), beta = degToRad(-2.0);
  std::vector<int> whole;
  for (int k = 0; k < f.unit.numApertures(); ++k) {
    const auto px = f.unit.spotPx(k, sunVectorFromAngles(alpha, beta));
    if (px && f.unit.insideDetector(*px, 10.0)) whole.push_back(k);
  }
  ASSERT_GE(whole.size(), 4u) << "the draw should show four whole spots";
  const int moved = whole.front();
  MaskGeometry built = f.unit;
  built.apertures_um[static_cast<std::size_t>(moved)] += Eigen::Vector2d(1.5, -1.0);
  Sites sites;
  for (int k : whole)
    addSpot(sites, *built.spotPx(k, sunVectorFromAngles(alpha, beta)) * built.pitch_um, 1.0, f.config, 0);
  const auto solve = [&] {
    const auto s = solveGeometry(*f.geometry, tensorOf(sites.xy_um).view({-1, 2}), tensorOf(sites.weight),
                                 torch::tensor(sites.index), 1,
                                 torch::tensor({alpha, beta}, torch::kFloat64).view({1, 2}), optionsFor(f.config));
    return std::pair{(s.angles_rad - torch::tensor({alpha, beta}, torch::kFloat64)).abs().max().item<double>(),
                     s.residual_per_dof[0].item<double>()};
  };
  const auto [exact_error, exact_residual] = solve();
  std::vector<double> variance_um2(6, 0.0);
  variance_um2[static_cast<std::size_t>(moved)] = 100.0;
  f.geometry->setPositionVariance(variance_um2, 1e-4);
  EXPECT_EQ(f.geometry->groupPositionVariance().size(), 6u);
  EXPECT_DOUBLE_EQ(f.geometry->groupPositionVariance()[static_cast<std::size_t>(moved)], 1e6);
  const auto [weighted_error, weighted_residual] = solve();
  EXPECT_GT(exact_error, 1e-6);
  EXPECT_LT(weighted_error, 0.01 * exact_error);
  EXPECT_LT(weighted_residual, 0.01 * exact_residual);
  EXPECT_THROW(f.geometry->setPositionVariance({1.0, 2.0}, 1e-4), std::invalid_argument);
  EXPECT_THROW(f.geometry->setPositionVariance(variance_um2, 0.0), std::invalid_argument);
  f.geometry->setPositionVariance({}, 0.0);
  EXPECT_TRUE(f.geometry->groupPositionVariance().empty());
}

// The mismatch residual is the spots' against the geometry at the angles
// returned: where the plain solve stops short (here it takes no step at all,
// 0.05 deg from the answer), the step in the graph completes it, and the
// residual is that of the converged solve, not the shortfall's (measured at
// the plain solve's angles, an untrained thesis_ma head's threshold came out
// 152 311 times its level instead of 6.6).
TEST(GeometricHead, ResidualIsMeasuredAtTheReturnedAngles) {
  const Fixture f = makeFixture(5, 91);
  const double alpha = degToRad(1.0), beta = degToRad(-1.2);
  Sites sites;
  int whole = 0;
  for (int k = 0; k < f.unit.numApertures(); ++k) {
    const auto px = f.unit.spotPx(k, sunVectorFromAngles(alpha, beta));
    if (!px || !f.unit.insideDetector(*px, 10.0)) continue;
    // One spot 0.8 um off its aperture's place: a residual to measure.
    const Eigen::Vector2d moved = whole++ == 0 ? Eigen::Vector2d(0.8, 0.0) : Eigen::Vector2d::Zero();
    addSpot(sites, *px * f.unit.pitch_um + moved, 1.0, f.config, 0);
  }
  ASSERT_GE(whole, 3) << "the draw should show three whole spots";
  const auto solve = [&](int iterations) {
    auto options = optionsFor(f.config);
    options.association_rounds = 1;
    options.gauss_newton_iterations = iterations;
    return solveGeometry(
        *f.geometry, tensorOf(sites.xy_um).view({-1, 2}), tensorOf(sites.weight), torch::tensor(sites.index), 1,
        torch::tensor({alpha + degToRad(0.05), beta - degToRad(0.05)}, torch::kFloat64).view({1, 2}), options);
  };
  const auto converged = solve(5), short_stop = solve(0);
  const double residual = converged.residual_per_dof[0].item<double>();
  EXPECT_GT(residual, 0.0);
  EXPECT_LT((short_stop.angles_rad - converged.angles_rad).abs().max().item<double>(), 1e-7);
  EXPECT_NEAR(short_stop.residual_per_dof[0].item<double>(), residual, 0.01 * residual);
  EXPECT_NEAR(short_stop.residual_um[0].item<double>(), converged.residual_um[0].item<double>(),
              0.01 * converged.residual_um[0].item<double>());
}

TEST(GeometricHead, GradientsThroughTheSolveMatchFiniteDifferences) {
  const Fixture f = makeFixture(4, 77);
  Sites sites;
  const double alpha = degToRad(1.7), beta = degToRad(-3.2);
  for (int k = 0; k < f.unit.numApertures(); ++k) {
    const auto px = f.unit.spotPx(k, sunVectorFromAngles(alpha, beta));
    addSpot(sites, *px * f.unit.pitch_um + Eigen::Vector2d(0.3 * k, -0.2 * k), 1.0 + k, f.config, 0);
  }
  const auto xy = tensorOf(sites.xy_um).view({-1, 2});
  const auto index = torch::tensor(sites.index);
  const auto reference = torch::tensor({alpha, beta}, torch::kFloat64).view({1, 2});
  const auto options = optionsFor(f.config);
  // Site weights (the network's) and the mask height and aperture positions
  // (what a unit calibration fits).
  const auto weights = tensorOf(sites.weight).slice(0, 0, 30);
  const auto rest = tensorOf(sites.weight).slice(0, 30);
  test::expectGradientsMatch(
      [&](const std::vector<torch::Tensor>& in) {
        auto& geometry = const_cast<SensorGeometryImpl&>(*f.geometry);
        const auto saved_height = geometry.height_um, saved_apertures = geometry.apertures_um;
        geometry.height_um = in[1];
        geometry.apertures_um = in[2];
        const auto out =
            solveGeometry(geometry, xy, torch::cat({in[0], rest}), index, 1, reference, options).angles_rad;
        geometry.height_um = saved_height;
        geometry.apertures_um = saved_apertures;
        return out;
      },
      {weights, f.geometry->height_um.clone(), f.geometry->apertures_um.clone()}, 1e-6, 1e-6);
}

TEST(GeometricHead, ModelKeepsItsGeometryAsNamedValuesAndRoundTrips) {
  const Fixture f = makeFixture(5, 12);
  Model m = createModel(f.config, "resnet10_w16", 3);
  ASSERT_TRUE(m.meta.arch.geometric_head);
  EXPECT_EQ(m.meta.arch.geometric_apertures, 5);
  EXPECT_EQ(m.meta.arch.centroid_weighting, CentroidWeighting::kLearned);  // as asked; dss train defaults to intensity
  // The nominal design, by name: the height to the mask's mid-plane.
  const auto buffers = m.net->named_buffers();
  ASSERT_TRUE(buffers.contains("geometry.height_um"));
  EXPECT_DOUBLE_EQ(buffers["geometry.height_um"].item<double>(),
                   1000.0 * (f.config.mask.height_mm + 0.5 * f.config.mask.thickness_mm));
  EXPECT_DOUBLE_EQ(buffers["geometry.apertures_um"][4][1].item<double>(), f.config.mask.apertures[4].y_um);
  EXPECT_DOUBLE_EQ(buffers["geometry.glass_index"].item<double>(), f.config.cover_glass.refractive_index);
  // A unit's geometry (here its height) survives the file.
  {
    torch::NoGradGuard no_grad;
    m.net->geometry()->height_um.add_(12.5);
  }
  m.net->eval();
  const std::string path = ::testing::TempDir() + "/geometric.dssmodel";
  saveModel(m, path);
  const Model loaded = loadModel(path, &f.config);
  EXPECT_TRUE(loaded.meta.arch.geometric_head);
  EXPECT_DOUBLE_EQ(loaded.net->geometry()->height_um.item<double>(), buffers["geometry.height_um"].item<double>());
  const Renderer renderer(SensorInstance::nominalOf(f.config));
  std::vector<cv::Mat> images;
  for (int k = 0; k < 3; ++k)
    images.push_back(renderer.render(sunVectorFromAngles(degToRad(2.0 - 2 * k), degToRad(-1.5 + k)), 5 + k, nullptr));
  torch::NoGradGuard no_grad;
  const auto input = encodeImages(images, m.meta.input);
  const auto a = m.net->forward(input), b = loaded.net->forward(input);
  EXPECT_TRUE(torch::equal(a.angles, b.angles));
  EXPECT_TRUE(torch::equal(a.log_variance, b.log_variance));
  EXPECT_GE(a.spots_read.min().item<double>(), 1.0);
  std::remove(path.c_str());
  // Mirror-image inference is refused for it.
  std::string yaml = metadataToYaml(m.meta);
  const auto at = yaml.find("inference_symmetry: none");
  ASSERT_NE(at, std::string::npos);
  yaml.replace(at, std::string("inference_symmetry: none").size(), "inference_symmetry: dihedral");
  try {
    metadataFromYaml(yaml, "test");
    FAIL() << "a geometric head with mirror-image inference was accepted";
  } catch (const ModelError& e) {
    EXPECT_NE(std::string(e.what()).find("geometric head"), std::string::npos) << e.what();
  }
}

// An aperture-coded lattice (wide_ma) keeps its code head as the geometric
// head's coarse estimate: the code names each spot's aperture, which the
// solve's own search by explained light could not (it read wide_ma's
// untrained head 26 deg off). Untrained, every image over the +-60 deg field
// is associated right and solved within a few thousandths of a degree.
TEST(GeometricHead, CodedLatticeKeepsItsCodeAsTheCoarseEstimate) {
  const SensorConfig wide = loadSensorConfig(DSS_SOURCE_DIR "/config/sensors/wide_ma.yaml");
  ArchSpec arch = archPreset("resnet10_w16", wide.numSubFovClasses());
  arch.centroid_weighting = CentroidWeighting::kIntensity;
  HeadOptions geometric;
  geometric.head = "geometric";
  const Model model = createModel(wide, arch, 1, geometric);
  ASSERT_TRUE(model.meta.arch.geometric_head);
  ASSERT_TRUE(model.meta.arch.latticeHead());
  EXPECT_EQ(model.meta.arch.lattice_resolve, LatticeResolve::kCode);
  // A centred lattice without a code gives its head up to the centroid and the search.
  const SensorConfig ma = loadSensorConfig(DSS_SOURCE_DIR "/config/sensors/thesis_ma.yaml");
  const ModelMetadata ma_geometric = metadataFor(ma, archPreset("resnet10_w16", ma.numSubFovClasses()), geometric);
  EXPECT_TRUE(ma_geometric.arch.geometric_head);
  EXPECT_FALSE(ma_geometric.arch.latticeHead());

  const std::string path = ::testing::TempDir() + "/coded_geometric.dssmodel";
  saveModel(model, path);
  SscnnEstimator estimator(path, &wide);
  DatasetSpec spec;
  spec.count = 24;
  spec.seed = 71;
  spec.threads = 2;
  std::vector<cv::Mat> images;
  std::vector<ImageTruth> truths;
  DatasetGenerator(wide, spec).run([&](const DatasetItem& item) {
    images.push_back(item.image);
    truths.push_back(item.truth);
  });
  const auto estimates = estimator.estimate(images);
  ASSERT_EQ(estimates.size(), truths.size());
  for (std::size_t k = 0; k < estimates.size(); ++k) {
    ASSERT_TRUE(estimates[k].valid) << k << ": " << estimates[k].status;
    EXPECT_LT(std::abs(estimates[k].alpha_rad - truths[k].alpha_rad) * kDegPerRad, 0.03) << k;
    EXPECT_LT(std::abs(estimates[k].beta_rad - truths[k].beta_rad) * kDegPerRad, 0.03) << k;
  }
  std::remove(path.c_str());
}

// The placements a unit's coarse estimate may take reach both edges of the
// field: its offset moves the lattice centre's spot toward one of them.
TEST(GeometricHead, UnitPriorReachesBothEdgesOfTheField) {
  const SensorConfig wide = loadSensorConfig(DSS_SOURCE_DIR "/config/sensors/wide_ma.yaml");
  const double half_h_px = 0.5 * wide.detector.height_px, edge_rad = 1.1 * wide.fov.beta_max_deg * kRadPerDeg;
  const double scale_rad = degToRad(60.0);
  const GeometricPrior design = geometricPrior(wide, 9, scale_rad);
  for (const double offset_um : {40.0, -40.0}) {
    MaskGeometry unit = MaskGeometry::nominalOf(wide);
    unit.offset_y_um = offset_um;
    const GeometricPrior prior = geometricPrior(wide, unit, 9, scale_rad);
    EXPECT_DOUBLE_EQ(prior.extent_x, design.extent_x) << offset_um;
    EXPECT_GT(prior.extent_y, design.extent_y) << offset_um;
    for (const double beta_rad : {edge_rad, -edge_rad}) {
      MaskGeometry centre = unit;
      centre.apertures_um = {Eigen::Vector2d::Zero()};
      const auto spot = centre.spotPx(0, sunVectorFromAngles(0.0, beta_rad));
      ASSERT_TRUE(spot);
      EXPECT_GE(prior.extent_y * half_h_px, std::abs(spot->y()) - 1e-9) << offset_um << " um, " << beta_rad << " rad";
    }
  }
}

// The prior follows the head's geometry: a raised mask widens it
// (calibrate-height's moved design: its spots at the field's edge lie
// farther out), and the copy restores it exactly.
TEST(GeometricHead, PriorFollowsTheHeadsGeometry) {
  const SensorConfig wide = loadSensorConfig(DSS_SOURCE_DIR "/config/sensors/wide_ma.yaml");
  HeadOptions geometric;
  geometric.head = "geometric";
  Model model = createModel(wide, archPreset("resnet10_w16", wide.numSubFovClasses()), 1, geometric);
  ASSERT_GT(model.meta.arch.geometric_prior_size, 0);
  const auto [table, extent_x, extent_y] = model.net->geometricPriorCopy();
  ASSERT_TRUE(table.defined());
  MaskGeometry raised = model.net->geometry()->maskGeometry();
  raised.height_um += 30.0;
  setHeadGeometry(model, raised);
  EXPECT_EQ(model.net->geometry()->maskGeometry().height_um, raised.height_um);
  const auto [raised_table, raised_x, raised_y] = model.net->geometricPriorCopy();
  EXPECT_GT(raised_x, extent_x);
  EXPECT_GT(raised_y, extent_y);
  EXPECT_FALSE(torch::equal(raised_table, table));
  model.net->initGeometricPrior(table, extent_x, extent_y);
  const auto [restored, restored_x, restored_y] = model.net->geometricPriorCopy();
  EXPECT_TRUE(torch::equal(restored, table));
  EXPECT_EQ(restored_x, extent_x);
  EXPECT_EQ(restored_y, extent_y);
}

}  // namespace
}  // namespace dss
