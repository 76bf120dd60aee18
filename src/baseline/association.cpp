#include "digital_sun_sensor/baseline/association.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/sim/geometry.h"

namespace dss {
namespace {

// Matches predicted spots to detections (each used once, nearest first).
struct Matching {
  std::vector<SpotObservation> observations;
  std::vector<int> spot_indices;
  int misses = 0;
  double evidence = 0.0;  // detections and misses, without spot sizes
  double size_penalty = 0.0;
  double sum_sq_px = 0.0;
};

Matching matchPattern(const MaskGeometry& geometry, const std::vector<DetectedSpot>& spots, const Eigen::Vector3d& sun,
                      const AssociationOptions& options, bool use_sizes) {
  Matching m;
  struct Pair {
    double d2;
    int aperture, spot;
  };
  std::vector<Pair> pairs;
  // Centre on the detector: at least part of the spot must have been seen.
  std::vector<bool> on_detector(geometry.numApertures(), false), explained(geometry.numApertures(), false);
  std::vector<bool> edge_explained(spots.size(), false);
  for (int i = 0; i < geometry.numApertures(); ++i) {
    const auto p = geometry.spotPx(i, sun);
    // A spot whose centre lies up to a spot radius beyond the edge still shows.
    if (!p || !geometry.insideDetector(*p, -options.edge_margin_px)) continue;
    on_detector[i] = geometry.insideDetector(*p, 2.0);
    for (int j = 0; j < static_cast<int>(spots.size()); ++j) {
      const double d2 = (Eigen::Vector2d(spots[j].x_px, spots[j].y_px) - *p).squaredNorm();
      if (spots[j].touches_edge) {
        // Its centroid is pulled inward by the cut: a loose gate.
        if (d2 < options.edge_margin_px * options.edge_margin_px) edge_explained[j] = explained[i] = true;
      } else if (d2 < options.gate_px * options.gate_px) {
        pairs.push_back({d2, i, j});
      }
    }
  }
  std::sort(pairs.begin(), pairs.end(), [](const Pair& a, const Pair& b) { return a.d2 < b.d2; });
  std::vector<bool> aperture_used(geometry.numApertures(), false), spot_used(spots.size(), false);
  for (const auto& p : pairs) {
    if (aperture_used[p.aperture] || spot_used[p.spot]) continue;
    aperture_used[p.aperture] = spot_used[p.spot] = explained[p.aperture] = true;
    m.observations.push_back({p.aperture, Eigen::Vector2d(spots[p.spot].x_px, spots[p.spot].y_px)});
    m.spot_indices.push_back(p.spot);
    m.sum_sq_px += p.d2;
  }
  // Evidence: a detection an aperture explains counts up to 1 (less for an
  // aperture rarely seen: a dim spot is a weaker match), an edge-cut one
  // half; a missing spot counts against in proportion to how often it is seen.
  auto probability = [&](int i) {
    return options.detection_probability.empty() ? 1.0 : std::clamp(options.detection_probability[i], 0.0, 1.0);
  };
  for (const auto& o : m.observations) m.evidence += 0.5 + 0.5 * probability(o.aperture);
  m.evidence += 0.5 * static_cast<double>(std::count(edge_explained.begin(), edge_explained.end(), true));
  for (int i = 0; i < geometry.numApertures(); ++i) {
    if (!on_detector[i] || explained[i]) continue;
    ++m.misses;
    m.evidence -= 0.5 * probability(i);
  }
  if (use_sizes && m.observations.size() >= 2) {
    // Spot area scales with aperture area: compare log ratios about their mean.
    std::vector<double> log_ratio;
    for (std::size_t k = 0; k < m.observations.size(); ++k) {
      const double d = geometry.aperture_diameters_um[m.observations[k].aperture];
      log_ratio.push_back(std::log(std::max(1, spots[m.spot_indices[k]].area_px)) - 2.0 * std::log(d));
    }
    double mean = 0.0;
    for (double v : log_ratio) mean += v / log_ratio.size();
    for (double v : log_ratio) m.size_penalty += (v - mean) * (v - mean);
  }
  return m;
}

bool insideFov(const SunSolution& s, const AssociationOptions& options) {
  return s.ok && std::abs(s.alpha_rad) <= options.fov_alpha_rad && std::abs(s.beta_rad) <= options.fov_beta_rad;
}

}  // namespace

AssociationOptions AssociationOptions::forSensor(const SensorConfig& config, const MaskGeometry& geometry) {
  AssociationOptions o;
  // 10% beyond the field of view: the sun may stray past it and still be seen.
  o.fov_alpha_rad = std::min(1.5, 1.1 * config.fov.alpha_max_deg * kRadPerDeg + 0.5 * kRadPerDeg);
  o.fov_beta_rad = std::min(1.5, 1.1 * config.fov.beta_max_deg * kRadPerDeg + 0.5 * kRadPerDeg);
  double max_diameter = 0.0;
  for (double d : geometry.aperture_diameters_um) max_diameter = std::max(max_diameter, d);
  const double min_spacing = geometry.minApertureSpacingUm();
  // Spot radius: aperture plus the solar disk's blur.
  const double sun_blur_um = geometry.height_um * std::tan(0.5 * config.optics.sun.angular_diameter_deg * kRadPerDeg);
  o.edge_margin_px = (0.5 * max_diameter + sun_blur_um) / geometry.pitch_um + 3.0;
  o.gate_px = geometry.numApertures() > 1 ? std::clamp(0.25 * min_spacing / geometry.pitch_um, 2.0, 10.0) : 10.0;
  return o;
}

std::optional<Association> associateSpots(const MaskGeometry& geometry, const std::vector<DetectedSpot>& spots,
                                          const AssociationOptions& options) {
  if (spots.empty() || geometry.numApertures() == 0) return std::nullopt;
  bool sizes_differ = false;
  for (double d : geometry.aperture_diameters_um)
    sizes_differ |= std::abs(d - geometry.aperture_diameters_um[0]) > 1e-6;

  std::optional<Association> best;
  double best_score = -std::numeric_limits<double>::max(), best_sq = 0.0;
  int anchors_left = options.anchors;
  for (int j = 0; j < static_cast<int>(spots.size()) && anchors_left > 0; ++j) {
    if (spots[j].touches_edge) continue;  // cut spots have biased centroids
    --anchors_left;
    for (int i = 0; i < geometry.numApertures(); ++i) {
      const SunSolution guess = solveSun(geometry, {{i, Eigen::Vector2d(spots[j].x_px, spots[j].y_px)}});
      if (!insideFov(guess, options)) continue;
      const Eigen::Vector3d sun = sunVectorFromAngles(guess.alpha_rad, guess.beta_rad);
      const Matching m = matchPattern(geometry, spots, sun, options, sizes_differ);
      const double score = m.evidence - options.size_weight * m.size_penalty;
      if (score > best_score || (score == best_score && m.sum_sq_px < best_sq)) {
        best_score = score;
        best_sq = m.sum_sq_px;
        best = Association{m.observations, m.spot_indices, guess, m.misses};
      }
    }
  }
  if (!best || best->observations.empty()) return std::nullopt;
  // Refine on every match, re-match once at the refined direction, solve again.
  best->solution = solveSun(geometry, best->observations);
  if (!best->solution.ok) return std::nullopt;
  const Matching m = matchPattern(
      geometry, spots, sunVectorFromAngles(best->solution.alpha_rad, best->solution.beta_rad), options, false);
  if (m.observations.size() >= best->observations.size()) {
    best->observations = m.observations;
    best->spot_indices = m.spot_indices;
    best->misses = m.misses;
    best->solution = solveSun(geometry, best->observations);
  }
  if (!insideFov(best->solution, options)) return std::nullopt;
  return best;
}

Association associateWithKnownSun(const MaskGeometry& geometry, const std::vector<DetectedSpot>& spots,
                                  const Eigen::Vector3d& sun, double gate_px) {
  AssociationOptions options;
  options.gate_px = gate_px;
  const Matching m = matchPattern(geometry, spots, sun, options, false);
  Association a;
  a.observations = m.observations;
  a.spot_indices = m.spot_indices;
  a.misses = m.misses;
  return a;
}

}  // namespace dss
