// Whole lattice pitches from where the spots are: the aperture code, for
// masks whose aperture diameters differ so that the visible spots tell which
// apertures they come from (wide_ma: every 2 x 2 neighbourhood of diameters
// is unique), and the spots' presence along each axis for the other
// lattices. Internal to the SSCNN head (torch).
#pragma once

#include <torch/types.h>

namespace dss {

// Fewer lit sites than this in a lattice cell (or column, or row): no spot there.
constexpr int kMinSpotSites = 5;

struct LatticeCode {
  double pitch_x = 0.0, pitch_y = 0.0;  // normalized detector units
  int columns = 1, rows = 1;
  torch::Tensor log_area;  // [rows, columns]: log open area of each lattice node's aperture
  // A cell whose spot centre lies nearer the detector edge than this may be
  // cut: its size is not compared, and its absence is no evidence.
  double edge_margin = 0.1;
  double max_shift_x = 1e9, max_shift_y = 1e9;  // |lattice-centre position| the field of view allows
  int min_spot_sites = kMinSpotSites;
};

// The aperture code's choice per image.
struct CodePlacement {
  torch::Tensor steps;  // [B, 2]: lattice-centre spot position minus the phase
  // [B], >= 1: the runner-up placement's score over the chosen one's. Near 1,
  // another whole-pitch placement explains the spots about as well (stray
  // light swelling the spots unevenly): the aperture is ambiguous.
  torch::Tensor margin;
};

// For each image, the lattice-centre spot position minus the phase (whole
// pitches, plus half a pitch for an even count), chosen among every
// placement of the aperture lattice over the cells the spots occupy: fewest
// contradictions (a lit cell no aperture explains, a wholly visible aperture
// with no spot), then the spot sizes (variance of the lit sites along each
// axis, where the spot is not cut across it) that best follow the apertures'
// areas, up to a common factor per axis; and its margin over the runner-up.
// Not differentiable.
// phase [B, 2]; xy [N, 2] site positions; lit [N] 1 for a lit site; index [N]
// image of each site.
CodePlacement codeLatticePlacement(const LatticeCode& code, const torch::Tensor& phase, const torch::Tensor& xy,
                                   const torch::Tensor& lit, const torch::Tensor& index, std::int64_t batch);

// One axis of a lattice whose whole pitches the centroid resolves
// (LatticeResolve::kCentroid): for each candidate placement, the lattice
// centre's spot at phase + steps[k] (normalized), the cells along the axis
// (columns or rows of spots, one pitch apart from the phase) that contradict
// it: a lit one (min_spot_sites or more lit sites) with no aperture there, or
// a dark one with an aperture there whose centre is wholly on the detector
// (edge_margin). Counted per column or row, a spot that a ghost or debris has
// dimmed below the threshold does not count against the right placement
// while its neighbours along the other axis are lit. Not differentiable.
// phase [B]; steps [K]; position [N] of the sites along the axis; lit [N];
// index [N]. Returns [B, K].
torch::Tensor axisContradictions(double pitch, int count, double edge_margin, int min_spot_sites,
                                 const torch::Tensor& phase, const torch::Tensor& steps, const torch::Tensor& position,
                                 const torch::Tensor& lit, const torch::Tensor& index, std::int64_t batch);

}  // namespace dss
