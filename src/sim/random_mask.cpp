#include "digital_sun_sensor/sim/random_mask.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/sim/geometry.h"
#include "digital_sun_sensor/sim/renderer.h"
#include "digital_sun_sensor/sim/sensor_instance.h"

namespace dss {
namespace {

double meanWavelengthUm(const OpticsConfig& optics) {
  double sum = 0.0, weight = 0.0;
  for (std::size_t i = 0; i < optics.wavelengths_um.size(); ++i) {
    const double w = i < optics.spectral_weights.size() ? optics.spectral_weights[i] : 1.0;
    sum += w * optics.wavelengths_um[i];
    weight += w;
  }
  return weight > 0.0 ? sum / weight : 0.55;
}

// Attitudes on which the spot counts are checked: a nodes x nodes grid over
// the field, its corners included.
std::vector<Eigen::Vector3d> fieldGrid(const FieldOfViewConfig& fov, int nodes) {
  std::vector<Eigen::Vector3d> suns;
  for (int i = 0; i < nodes; ++i)
    for (int j = 0; j < nodes; ++j)
      suns.push_back(sunVectorFromAngles(degToRad(fov.alpha_max_deg * (2.0 * i / (nodes - 1) - 1.0)),
                                         degToRad(fov.beta_max_deg * (2.0 * j / (nodes - 1) - 1.0))));
  return suns;
}

// Fewest whole spots that show light (a few lit pixels within a spot radius
// of their centre) in the design's noise-free, thresholded images.
int fewestLitSpots(const SensorConfig& config, const std::vector<Eigen::Vector3d>& suns, double spot_radius_um) {
  constexpr int kMinLitPixels = 4;
  const Renderer renderer(SensorInstance::nominalOf(config));
  RenderOptions quiet;
  quiet.noise = false;
  quiet.anomalies = false;
  const double pitch = config.detector.pitch_um, radius_px = spot_radius_um / pitch;
  const double half_w = 0.5 * config.detector.width_px - radius_px,
               half_h = 0.5 * config.detector.height_px - radius_px;
  int fewest = std::numeric_limits<int>::max();
  for (const auto& sun : suns) {
    ImageTruth truth;
    cv::Mat image;
    renderer.render(sun, 1, &truth, quiet).convertTo(image, CV_32F);
    int lit_spots = 0;
    for (const auto& spot : truth.spots) {
      if (!spot.on_detector || std::abs(spot.x_px) >= half_w || std::abs(spot.y_px) >= half_h) continue;
      const double cx = spot.x_px + 0.5 * config.detector.width_px, cy = spot.y_px + 0.5 * config.detector.height_px;
      int lit = 0;
      for (int y = std::max(0, static_cast<int>(cy - radius_px));
           y <= std::min(image.rows - 1, static_cast<int>(cy + radius_px)); ++y)
        for (int x = std::max(0, static_cast<int>(cx - radius_px));
             x <= std::min(image.cols - 1, static_cast<int>(cx + radius_px)); ++x)
          if (image.at<float>(y, x) > 0.0f && std::hypot(x + 0.5 - cx, y + 0.5 - cy) <= radius_px) ++lit;
      if (lit >= kMinLitPixels) ++lit_spots;
    }
    fewest = std::min(fewest, lit_spots);
  }
  return fewest;
}

// Fewest spots wholly on the detector (centre at least a spot radius inside
// the edge) over the attitudes.
int fewestWholeSpots(const SensorConfig& config, const std::vector<Eigen::Vector3d>& suns, double spot_radius_um) {
  const double half_w = 0.5 * config.detector.width_px * config.detector.pitch_um - spot_radius_um;
  const double half_h = 0.5 * config.detector.height_px * config.detector.pitch_um - spot_radius_um;
  const GlassSlab glass{config.cover_glass.enabled ? config.cover_glass.thickness_mm * 1000.0 : 0.0,
                        config.cover_glass.refractive_index};
  int fewest = std::numeric_limits<int>::max();
  for (const auto& sun : suns) {
    int whole = 0;
    for (const auto& a : config.mask.apertures) {
      const auto hit = traceToDetector({a.x_um, a.y_um, config.mask.height_mm * 1000.0}, sun, glass);
      if (hit && std::abs(hit->x()) < half_w && std::abs(hit->y()) < half_h) ++whole;
    }
    fewest = std::min(fewest, whole);
  }
  return fewest;
}

}  // namespace

double spotDiameterUm(const SensorConfig& config, double aperture_diameter_um) {
  const double height_um = config.mask.height_mm * 1000.0;
  const double diffraction_um = 2.44 * meanWavelengthUm(config.optics) * height_um / aperture_diameter_um;
  const double disk_um = config.optics.sun.enabled ? height_um * degToRad(config.optics.sun.angular_diameter_deg) : 0.0;
  return aperture_diameter_um + diffraction_um + disk_um;
}

RandomMask drawRandomMask(const SensorConfig& base, const RandomMaskOptions& options, std::uint64_t seed,
                          const std::string& name) {
  if (options.apertures < 1 || options.apertures > 64)
    throw std::invalid_argument("random mask: apertures must be 1..64, not " + std::to_string(options.apertures));
  if (!(options.diameter_spread >= 0.0 && options.diameter_spread < 1.0))
    throw std::invalid_argument("random mask: diameter_spread must be in [0, 1)");
  if (options.min_whole_spots < 1 || options.min_whole_spots > options.apertures)
    throw std::invalid_argument("random mask: min_whole_spots must be 1..apertures (" +
                                std::to_string(options.apertures) + ")");
  if (options.min_lit_spots < 0 || options.min_lit_spots > options.min_whole_spots)
    throw std::invalid_argument("random mask: min_lit_spots must be 0..min_whole_spots (" +
                                std::to_string(options.min_whole_spots) + ")");
  if (base.mask.apertures.empty() && !(options.diameter_um > 0.0))
    throw std::invalid_argument("random mask: the base config has no aperture; give a diameter");
  const double diameter_um =
      options.diameter_um > 0.0 ? options.diameter_um : base.mask.apertures.front().equivalentDiameterUm();
  RandomMask out;
  out.spot_diameter_um = spotDiameterUm(base, diameter_um * (1.0 + options.diameter_spread));
  const double min_spacing_um = options.min_separation_spots * out.spot_diameter_um;
  // Spots of apertures beyond the detector's half size plus the field's
  // largest shift never reach it.
  const double height_um = base.mask.height_mm * 1000.0;
  const double reach_x_um =
      0.5 * base.detector.width_px * base.detector.pitch_um + height_um * std::tan(degToRad(base.fov.alpha_max_deg));
  const double reach_y_um =
      0.5 * base.detector.height_px * base.detector.pitch_um + height_um * std::tan(degToRad(base.fov.beta_max_deg));
  const auto suns = fieldGrid(base.fov, 9);
  const auto rendered_suns = fieldGrid(base.fov, 5);
  Rng rng(deriveSeed(seed, 0x6d61736bULL));
  constexpr int kMaxDraws = 20000;
  constexpr int kMaxLitChecks = 20;  // renders cost seconds per draw
  int lit_checks = 0, fewest_lit_seen = -1;
  for (int draw = 1; draw <= kMaxDraws; ++draw) {
    SensorConfig config = base;
    config.mask.apertures.clear();
    // Positions one at a time, each redrawn (up to 200 times) until it keeps
    // the spacing; a mask that cannot place one more aperture starts over.
    for (int k = 0; k < options.apertures; ++k) {
      bool placed = false;
      for (int attempt = 0; attempt < 200 && !placed; ++attempt) {
        const double x = rng.uniform(-reach_x_um, reach_x_um), y = rng.uniform(-reach_y_um, reach_y_um);
        placed = std::all_of(config.mask.apertures.begin(), config.mask.apertures.end(),
                             [&](const auto& a) { return std::hypot(a.x_um - x, a.y_um - y) >= min_spacing_um; });
        if (!placed) continue;
        ApertureConfig a;
        a.x_um = std::round(x * 100.0) / 100.0;  // as a config file would give them
        a.y_um = std::round(y * 100.0) / 100.0;
        a.shape = ApertureShape::kCircle;
        a.diameter_um = diameter_um * (1.0 + options.diameter_spread * rng.uniform(-1.0, 1.0));
        a.diameter_um = std::round(a.diameter_um * 100.0) / 100.0;
        config.mask.apertures.push_back(a);
      }
      if (!placed) break;
    }
    if (static_cast<int>(config.mask.apertures.size()) < options.apertures) continue;
    const int whole = fewestWholeSpots(config, suns, 0.5 * out.spot_diameter_um);
    if (whole < options.min_whole_spots) continue;
    if (options.min_lit_spots > 0) {
      out.min_lit_spots = fewestLitSpots(config, rendered_suns, 0.5 * out.spot_diameter_um);
      fewest_lit_seen = std::max(fewest_lit_seen, out.min_lit_spots);
      if (out.min_lit_spots < options.min_lit_spots) {
        if (++lit_checks < kMaxLitChecks) continue;
        throw std::invalid_argument(
            "random mask: none of " + std::to_string(kMaxLitChecks) + " draws with " +
            std::to_string(options.min_whole_spots) + " whole spots kept " + std::to_string(options.min_lit_spots) +
            " of them lit over the field (at best " + std::to_string(fewest_lit_seen) +
            "): the threshold, relative to the brightest pixel, leaves the dimmer spots dark (apertures alike, a "
            "lower threshold or more whole spots)");
      }
    }
    config.name = name.empty() ? base.name + "_random_" + std::to_string(seed) : name;
    config.source_path.clear();
    out.config = config;
    out.min_spacing_um = std::numeric_limits<double>::infinity();
    for (std::size_t i = 0; i < config.mask.apertures.size(); ++i)
      for (std::size_t j = 0; j < i; ++j)
        out.min_spacing_um =
            std::min(out.min_spacing_um, std::hypot(config.mask.apertures[i].x_um - config.mask.apertures[j].x_um,
                                                    config.mask.apertures[i].y_um - config.mask.apertures[j].y_um));
    out.min_whole_spots = whole;
    out.draws = draw;
    return out;
  }
  throw std::invalid_argument("random mask: no draw of " + std::to_string(options.apertures) +
                              " apertures kept spots " + std::to_string(min_spacing_um) + " um apart with " +
                              std::to_string(options.min_whole_spots) +
                              " whole spots over the field in 20000 tries (fewer apertures, fewer whole spots, a "
                              "smaller separation or field)");
}

}  // namespace dss
