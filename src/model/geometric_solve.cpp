#include "geometric_solve.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>
#include <vector>

#include "digital_sun_sensor/baseline/symmetry_centre.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/sim/geometry.h"

namespace dss::geometric {
namespace {

constexpr double kFar = 1e12;  // um: where a spot no ray reaches lies
constexpr double kMaxAngle = 1.4;

std::vector<Eigen::Vector2d> apertureSpots(const Design& design, const Eigen::Vector2d& angles) {
  const Eigen::Vector3d sun = sunVectorFromAngles(angles.x(), angles.y());
  std::vector<Eigen::Vector2d> spots;
  spots.reserve(static_cast<std::size_t>(design.mask.numApertures()));
  for (int k = 0; k < design.mask.numApertures(); ++k) {
    const auto p = design.mask.spotPx(k, sun);
    spots.push_back(p ? *p : Eigen::Vector2d(kFar, kFar));
  }
  return spots;
}

// d(group spots)/d(angles) by central differences.
std::vector<Eigen::Matrix2d> jacobians(const Design& design, const Eigen::Vector2d& angles) {
  constexpr double kStep = 1e-6;
  std::vector<Eigen::Matrix2d> j(static_cast<std::size_t>(design.groups));
  for (int axis = 0; axis < 2; ++axis) {
    Eigen::Vector2d d = Eigen::Vector2d::Zero();
    d[axis] = kStep;
    const auto plus = groupSpots(design, angles + d), minus = groupSpots(design, angles - d);
    for (std::size_t g = 0; g < j.size(); ++g) j[g].col(axis) = (plus[g] - minus[g]) / (2.0 * kStep);
  }
  return j;
}

// Sides of the detector a cut spot crosses (bits of Reading::cut).
constexpr char kCutRight = 1, kCutLeft = 2, kCutTop = 4, kCutBottom = 8;

// A cut spot's centre along the axes whose edge it crosses: the vertex of
// the isotropic quadratic w = q0 + q1 x + q2 y + q3 (x^2 + y^2) fitted to its
// sites' weights, whose curvature the light along the edge and on the far
// side fixes (a spot whose light falls off alike in every direction from its
// centre). Along an axis with no cut (or cut at both ends) the centroid
// stays. The sites keep their weights and are moved by the centre's change,
// so that their centroid is the centre and its spread theirs. Nothing moves
// where the fit finds no peak or puts it more than the spot's extent away.
void fitCutSpot(const std::vector<Site>& sites, const std::vector<std::size_t>& members, char cut, Reading& r) {
  const bool along[2] = {((cut & kCutRight) != 0) != ((cut & kCutLeft) != 0),
                         ((cut & kCutTop) != 0) != ((cut & kCutBottom) != 0)};
  if (!along[0] && !along[1]) return;
  Eigen::Vector2d centroid = Eigen::Vector2d::Zero();
  double sum = 0.0, extent2 = 0.0;
  for (std::size_t i : members) {
    centroid += sites[i].weight * sites[i].um;
    sum += sites[i].weight;
  }
  if (!(sum > 0.0) || members.size() < 6) return;
  centroid /= sum;
  Eigen::Matrix4d a = Eigen::Matrix4d::Zero();
  Eigen::Vector4d b = Eigen::Vector4d::Zero();
  for (std::size_t i : members) {
    const Eigen::Vector2d d = sites[i].um - centroid;
    extent2 = std::max(extent2, d.squaredNorm());
    const Eigen::Vector4d f(1.0, d.x(), d.y(), d.squaredNorm());
    a += f * f.transpose();
    b += f * sites[i].weight;
  }
  const Eigen::Vector4d q = a.ldlt().solve(b);
  if (!q.allFinite() || !(q[3] < 0.0)) return;
  Eigen::Vector2d shift(-q[1] / (2.0 * q[3]), -q[2] / (2.0 * q[3]));
  for (int axis = 0; axis < 2; ++axis)
    if (!along[axis]) shift[axis] = 0.0;
  if (!shift.allFinite() || shift.squaredNorm() > extent2) return;
  for (std::size_t i : members) r.read_um[i] = sites[i].um + shift;
}

// A whole spot read at its point of symmetry: its sites' weights placed on
// the pixel grid (dark around them) and fitted from their centroid; the
// sites are read moved by the change, as a cut spot's. Sites off the grid
// (not at pixel centres) or a failed fit leave the centroid.
void fitSymmetricSpot(const std::vector<Site>& sites, const std::vector<std::size_t>& members, const Options& options,
                      Reading& r) {
  constexpr int kMargin = 3;  // dark pixels around the lit ones: the mirror image's taps reach them
  if (members.size() < 4) return;
  const double cx = 0.5 * (options.width_px - 1), cy = 0.5 * (options.height_px - 1);
  std::vector<Eigen::Vector2i> pixel;
  pixel.reserve(members.size());
  Eigen::Vector2i lo(std::numeric_limits<int>::max(), std::numeric_limits<int>::max()), hi = -lo;
  Eigen::Vector2d centroid = Eigen::Vector2d::Zero();
  double sum = 0.0;
  for (std::size_t i : members) {
    const Eigen::Vector2d p(sites[i].um.x() / options.pitch_um + cx, sites[i].um.y() / options.pitch_um + cy);
    const Eigen::Vector2i q(static_cast<int>(std::lround(p.x())), static_cast<int>(std::lround(p.y())));
    if ((p - q.cast<double>()).cwiseAbs().maxCoeff() > 0.01) return;
    pixel.push_back(q);
    lo = lo.cwiseMin(q);
    hi = hi.cwiseMax(q);
    centroid += sites[i].weight * p;
    sum += sites[i].weight;
  }
  if (!(sum > 0.0)) return;
  centroid /= sum;
  SymmetryPatch patch;
  patch.cols = hi.x() - lo.x() + 1 + 2 * kMargin;
  patch.rows = hi.y() - lo.y() + 1 + 2 * kMargin;
  patch.values.assign(static_cast<std::size_t>(patch.cols) * static_cast<std::size_t>(patch.rows), 0.0);
  const Eigen::Vector2i origin = lo - Eigen::Vector2i::Constant(kMargin);
  for (std::size_t k = 0; k < members.size(); ++k) {
    const Eigen::Vector2i q = pixel[k] - origin;
    patch.values[static_cast<std::size_t>(q.y()) * static_cast<std::size_t>(patch.cols) +
                 static_cast<std::size_t>(q.x())] = sites[members[k]].weight;
  }
  const auto centre = symmetryCentre(patch, centroid - origin.cast<double>());
  if (!centre) return;
  const Eigen::Vector2d shift = (*centre + origin.cast<double>() - centroid) * options.pitch_um;
  for (std::size_t i : members) r.read_um[i] = sites[i].um + shift;
}

}  // namespace

Reading readSpots(const Design& design, const std::vector<Site>& sites, const Eigen::Vector2d& angles, double radius_um,
                  const Options& options, bool fit_cut) {
  const auto spots = apertureSpots(design, angles);
  const double edge_x = 0.5 * (options.width_px - 2) * options.pitch_um;
  const double edge_y = 0.5 * (options.height_px - 2) * options.pitch_um;
  const auto groups = static_cast<std::size_t>(design.groups);
  Reading r;
  r.group.resize(sites.size());
  r.distance2.resize(sites.size());
  r.read_um.resize(sites.size());
  r.sum.assign(groups, 0.0);
  r.spread.assign(groups, 0.0);
  r.centroid.assign(groups, Eigen::Vector2d::Zero());
  r.cut.assign(groups, 0);
  std::vector<std::vector<std::size_t>> members(groups);
  // The spots within the radius of the detector (wide_ma: 9-16 of 49) are
  // searched first: a site whose nearest of them lies within the radius has
  // it as its nearest of all; any other site gets the whole search.
  const double reach_x = 0.5 * options.width_px * options.pitch_um + radius_um;
  const double reach_y = 0.5 * options.height_px * options.pitch_um + radius_um;
  std::vector<std::size_t> near_detector, all(spots.size());
  for (std::size_t k = 0; k < spots.size(); ++k) {
    all[k] = k;
    if (std::abs(spots[k].x()) <= reach_x && std::abs(spots[k].y()) <= reach_y) near_detector.push_back(k);
  }
  auto nearestOf = [&](const Eigen::Vector2d& um, const std::vector<std::size_t>& candidates, double& best) {
    best = std::numeric_limits<double>::infinity();
    int nearest = 0;
    for (std::size_t k : candidates) {
      const double d2 = (um - spots[k]).squaredNorm();
      if (d2 < best) {
        best = d2;
        nearest = static_cast<int>(k);
      }
    }
    return nearest;
  };
  for (std::size_t i = 0; i < sites.size(); ++i) {
    double best = 0.0;
    int nearest = nearestOf(sites[i].um, near_detector, best);
    if (!(best < radius_um * radius_um)) nearest = nearestOf(sites[i].um, all, best);
    r.distance2[i] = best;
    r.group[i] = design.group[static_cast<std::size_t>(nearest)];
    r.read_um[i] = sites[i].um;
    if (!(best < radius_um * radius_um)) continue;
    const auto g = static_cast<std::size_t>(r.group[i]);
    members[g].push_back(i);
    const Eigen::Vector2d& xy = sites[i].um;
    if (xy.x() > edge_x) r.cut[g] |= kCutRight;
    if (xy.x() < -edge_x) r.cut[g] |= kCutLeft;
    if (xy.y() > edge_y) r.cut[g] |= kCutTop;
    if (xy.y() < -edge_y) r.cut[g] |= kCutBottom;
  }
  for (std::size_t g = 0; g < groups; ++g) {
    if (fit_cut && r.cut[g]) fitCutSpot(sites, members[g], r.cut[g], r);
    if (fit_cut && !r.cut[g] && options.symmetric_spots) fitSymmetricSpot(sites, members[g], options, r);
    Eigen::Vector2d second = Eigen::Vector2d::Zero();
    for (std::size_t i : members[g]) {
      const double w = sites[i].weight;
      r.sum[g] += w;
      r.centroid[g] += w * r.read_um[i];
      second += w * r.read_um[i].cwiseProduct(r.read_um[i]);
    }
    const double safe = std::max(r.sum[g], 1e-30);
    r.centroid[g] /= safe;
    r.spread[g] = (second / safe - r.centroid[g].cwiseProduct(r.centroid[g])).sum();
  }
  return r;
}

std::vector<double> solveWeights(const Reading& r, const Options& options) {
  std::vector<double> all(r.sum.size(), 0.0), whole(r.sum.size(), 0.0);
  bool any_whole = false;
  for (std::size_t g = 0; g < r.sum.size(); ++g) {
    if (!(r.sum[g] > 0.0)) continue;
    all[g] = r.sum[g] / std::max(r.spread[g], options.pitch_um * options.pitch_um / 6.0);
    if (!options.group_variance.empty()) all[g] /= 1.0 + all[g] * options.group_variance[g];
    if (!r.cut[g]) {
      whole[g] = all[g];
      any_whole = true;
    }
  }
  return any_whole ? whole : all;
}

namespace {

Eigen::Matrix2d normalInverse(const std::vector<Eigen::Matrix2d>& j, const std::vector<double>& w) {
  Eigen::Matrix2d a = Eigen::Matrix2d::Zero();
  for (std::size_t g = 0; g < j.size(); ++g) a += w[g] * j[g].transpose() * j[g];
  const double det = a.determinant();
  return det > 1e-300 ? Eigen::Matrix2d(a.inverse()) : Eigen::Matrix2d::Zero();
}

Eigen::Vector2d clampAngles(const Eigen::Vector2d& a) {
  return {std::clamp(a.x(), -kMaxAngle, kMaxAngle), std::clamp(a.y(), -kMaxAngle, kMaxAngle)};
}

// Gauss-Newton from `angles` on the spots of one reading.
Eigen::Vector2d solveReading(const Design& design, const Reading& r, Eigen::Vector2d angles, const Options& options) {
  const auto w = solveWeights(r, options);
  for (int it = 0; it < options.iterations; ++it) {
    const auto j = jacobians(design, angles);
    const auto predicted = groupSpots(design, angles);
    Eigen::Vector2d b = Eigen::Vector2d::Zero();
    for (std::size_t g = 0; g < j.size(); ++g)
      if (w[g] > 0.0) b += w[g] * j[g].transpose() * (r.centroid[g] - predicted[g]);
    const Eigen::Vector2d step = normalInverse(j, w) * b;
    if (!step.allFinite()) break;
    angles = clampAngles(angles + step);
    if (step.norm() < 1e-13) break;
  }
  return angles;
}

// Rounds of association and Gauss-Newton from `angles`.
Eigen::Vector2d refine(const Design& design, const std::vector<Site>& sites, Eigen::Vector2d angles,
                       const Options& options) {
  for (int round = 0; round < options.rounds; ++round)
    angles = solveReading(design, readSpots(design, sites, angles, options.gate_um, options), angles, options);
  return angles;
}

// How well spots at the angles account for the light: the fraction of it
// within half a gate of a spot, less the fraction of the spots the detector
// should show (centre two pixels inside its edges) that are dark (under a
// tenth of the mean light of the spots that hold some). A spot centred just
// inside an edge still shows about half its light; the rule is relative to a
// spot's light, not the image's, since a spot of a 49-aperture mask holds 2 %.
struct Score {
  double explained = 0.0;  // fraction of the light within half a gate of a spot
  double dark = 0.0;       // fraction of the expected spots that are dark
  double total() const { return explained - dark; }
};

Score score(const Design& design, const std::vector<Site>& sites, const Eigen::Vector2d& angles,
            const Options& options) {
  const Reading r = readSpots(design, sites, angles, 0.5 * options.gate_um, options, false);
  double total = 0.0, explained = 0.0;
  int lit = 0;
  for (const auto& s : sites) total += s.weight;
  for (double sum : r.sum) {
    explained += sum;
    if (sum > 0.0) ++lit;
  }
  const double dark_below = 0.1 * explained / std::max(lit, 1);
  const auto spots = groupSpots(design, angles);
  const double limit_x = 0.5 * (options.width_px - 4) * options.pitch_um;
  const double limit_y = 0.5 * (options.height_px - 4) * options.pitch_um;
  int expected = 0, dark = 0;
  for (std::size_t g = 0; g < spots.size(); ++g) {
    if (std::abs(spots[g].x()) >= limit_x || std::abs(spots[g].y()) >= limit_y) continue;
    ++expected;
    if (!(r.sum[g] >= dark_below)) ++dark;
  }
  return {explained / std::max(total, 1e-30), static_cast<double>(dark) / std::max(expected, 1)};
}

// Apertures whose fluxes differ by more than a few percent.
bool aperturesDiffer(const Design& design) {
  if (design.flux.empty()) return false;
  const auto [least, most] = std::minmax_element(design.flux.begin(), design.flux.end());
  return *most > 1.05 * *least;
}

// Angles that put group g's spot at `target` (Newton from normal incidence).
Eigen::Vector2d placeGroup(const Design& design, int g, const Eigen::Vector2d& target) {
  Eigen::Vector2d angles = Eigen::Vector2d::Zero();
  for (int it = 0; it < 8; ++it) {
    const auto j = jacobians(design, angles)[static_cast<std::size_t>(g)];
    if (std::abs(j.determinant()) < 1e-12) break;
    const Eigen::Vector2d step = j.inverse() * (target - groupSpots(design, angles)[static_cast<std::size_t>(g)]);
    angles = clampAngles(angles + step);
    if (step.norm() < 1e-12) break;
  }
  return angles;
}

}  // namespace

std::vector<Eigen::Vector2d> groupSpots(const Design& design, const Eigen::Vector2d& angles_rad) {
  auto spots = apertureSpots(design, angles_rad);
  if (design.groups != design.mask.numApertures()) {
    std::vector<Eigen::Vector2d> sum(static_cast<std::size_t>(design.groups), Eigen::Vector2d::Zero());
    std::vector<double> flux(sum.size(), 0.0);
    for (std::size_t k = 0; k < spots.size(); ++k) {
      const auto g = static_cast<std::size_t>(design.group[k]);
      sum[g] += design.flux[k] * spots[k];
      flux[g] += design.flux[k];
    }
    for (std::size_t g = 0; g < sum.size(); ++g) sum[g] /= flux[g];
    spots = std::move(sum);
  }
  design.spot_bias.addTo(angles_rad, spots);
  return spots;
}

ImageSolution solveImage(const Design& design, const std::vector<Site>& sites, const Eigen::Vector2d& reference_rad,
                         const Options& options) {
  Eigen::Vector2d angles = clampAngles(reference_rad);
  // The association and the search read centroids; symmetric spots (a fit
  // per spot) are read once, where they found the angles.
  Options centroids = options;
  centroids.symmetric_spots = false;
  // The search's hypotheses, refined and scored, and the chosen one's score
  // (none without a search).
  std::vector<std::pair<Eigen::Vector2d, Score>> candidates;
  Score chosen;
  constexpr double kTieScore = 0.02;
  if (options.search && !sites.empty()) {
    // Hypotheses: the reference, and per group the angles that put its spot
    // on the brightest site (the first of equals), each refined and scored.
    // Of those that score within kTieScore of the best, the one nearest the
    // reference wins: a periodic mask whose edge row has left the detector
    // looks the same one pitch further (thesis_ma: 3 deg), and only the
    // network's coarse estimate can tell which.
    std::size_t anchor = 0;
    for (std::size_t i = 1; i < sites.size(); ++i)
      if (sites[i].weight > sites[anchor].weight) anchor = i;
    const Eigen::Vector2d start = refine(design, sites, angles, centroids);
    candidates.emplace_back(start, score(design, sites, start, options));
    for (int g = 0; g < design.groups; ++g) {
      const Eigen::Vector2d candidate = refine(design, sites, placeGroup(design, g, sites[anchor].um), centroids);
      candidates.emplace_back(candidate, score(design, sites, candidate, options));
    }
    double best = -std::numeric_limits<double>::infinity();
    for (const auto& c : candidates) best = std::max(best, c.second.total());
    const Eigen::Vector2d reference = angles;
    double nearest = std::numeric_limits<double>::infinity();
    for (const auto& c : candidates) {
      const double distance = (c.first - reference).squaredNorm();
      if (c.second.total() >= best - kTieScore && distance < nearest) {
        nearest = distance;
        angles = c.first;  // refined already
        chosen = c.second;
      }
    }
  } else {
    angles = refine(design, sites, angles, centroids);
  }
  const Reading r = readSpots(design, sites, angles, options.gate_um, options);
  if (options.symmetric_spots) angles = solveReading(design, r, angles, options);
  ImageSolution out;
  out.angles_rad = angles;
  // One lit spot on a mask whose apertures differ: ambiguous when another
  // hypothesis explains the light as well (a dimmer aperture's spot may be
  // under the threshold, so dark spots do not decide).
  const auto lit = std::count_if(r.sum.begin(), r.sum.end(), [](double s) { return s > 0.0; });
  if (lit == 1 && design.groups > 1 && aperturesDiffer(design)) {
    const double distinct = degToRad(ImageSolution::kDistinctDeg);
    out.lone_spot_ambiguous = std::any_of(candidates.begin(), candidates.end(), [&](const auto& c) {
      return (c.first - angles).norm() > distinct && c.second.explained >= chosen.explained - kTieScore;
    });
  }
  out.group.resize(sites.size());
  for (std::size_t i = 0; i < sites.size(); ++i)
    out.group[i] = r.distance2[i] < options.gate_um * options.gate_um ? r.group[i] : -1;
  out.read_um = r.read_um;
  out.weight = solveWeights(r, options);
  out.jacobian = jacobians(design, angles);
  out.normal_inverse = normalInverse(out.jacobian, out.weight);
  return out;
}

}  // namespace dss::geometric
