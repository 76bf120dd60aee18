// SSCNN architectures: the published SparseResNet34 layout and lighter
// variants. Torch-free: the spec travels in model-file metadata.
#pragma once

#include <string>
#include <vector>

namespace dss {

// How the lattice head takes whole pitches: from the coarse centroid (spots
// leaving the detector tell the lattice apart), from the sub-FOV class (the
// classifier tells the apertures apart), or from the aperture code (spot
// sizes matched against a mask whose diameters differ, src/model/lattice_code;
// the classes are the apertures, as with kClass).
enum class LatticeResolve { kCentroid, kClass, kCode };

// How the centroid branch weighs each lit site: by a learned function of its
// neighbourhood alone (equal weights at the start), by its value times a
// learned factor (1 at the start: the intensity-weighted centroid, the
// baseline's), or by its value alone (nothing learned: on wide_ma the learned
// factor cost accuracy under stray light). A weight that does not vanish at
// the threshold makes pixels flickering across it jump the centroid.
enum class CentroidWeighting { kLearned, kValue, kIntensity };
const char* centroidWeightingName(CentroidWeighting weighting);
// Throws std::invalid_argument for a name other than "learned", "value" or "intensity".
CentroidWeighting parseCentroidWeighting(const std::string& name);

// Choices of the head that follow the mask (set when a model is created, then
// recorded in the ArchSpec of its file).
struct HeadOptions {
  // Lattice masks: read the whole spots spot by spot (ArchSpec::
  // lattice_spotwise_phase); false gives the head of the models made before it
  // (the shipped thesis_ma).
  bool lattice_spotwise_phase = true;
  // Which head solves the angles: "auto" (the pattern head for a mask whose
  // spots merge, the geometric head for any other mask of several apertures
  // that is not a full centred lattice, else the mask-family heads),
  // "geometric", "pattern" or "classic" (the mask-family heads).
  std::string head = "auto";
};
// "auto", "geometric", "pattern", "classic"; throws std::invalid_argument for another.
void validateHeadChoice(const std::string& head);
struct ArchSpec;
// The head an architecture holds: "geometric", "pattern" or "classic".
std::string headName(const ArchSpec& arch);

struct ArchSpec {
  std::string name;
  int input_channels = 3;  // pixel value, x, y
  int stem_width = 64;
  int stem_kernel = 7;                  // strided sparse conv, stride 2
  bool stem_max_pool = true;            // 3x3 stride-2 sparse max pool
  std::vector<int> blocks{3, 4, 6, 3};  // residual blocks per stage; stages after the first halve resolution
  std::vector<int> widths{64, 128, 256, 512};
  bool batch_norm = false;    // the published network has none
  bool centroid_pool = true;  // learned intensity-weighted centroid of the input sites
  int centroid_width = 16;    // channels of its weighting branch
  CentroidWeighting centroid_weighting = CentroidWeighting::kLearned;
  // The pixel value v (full scale 1) enters the value and intensity weights as
  // v / (1 + value_saturation * v); 0: as v. The brightest pixels carry the
  // most noise (shot and PRNU) for no more position than their neighbours, so
  // a saturating weight lowers the spots' noise where the spots are broad
  // (measured: docs/sscnn.md#value-saturation).
  double value_saturation = 0.0;
  int centroid_degree = 3;  // the angles get a learned polynomial of the centroid (degree 1..this)
  // Learned angle terms are multiplied by this (normalized units): on top of the
  // physics prior they are corrections, and Adam's per-step change of a weight
  // is about the learning rate whatever the gradient's size, so their scale
  // sets the finest step the optimizer takes on the angles.
  double residual_scale = 0.02;
  // The angles get corrections from the pooled backbone features (the MLP)
  // besides the polynomial of the position. Off, the angles are a smooth
  // function of the position alone (prior + polynomial; the learned centroid
  // weights, class and variance branches still train): on wide_ma the MLP's
  // corrections jumped with the position (docs/results/wide_ma.md).
  bool feature_corrections = true;
  // Masks whose apertures form a regular, centred lattice of columns x rows:
  // the head reads the spot shift modulo the lattice pitch (circular mean of
  // the weighted site positions, normalized units) and adds whole pitches
  // (LatticeResolve). A plain centroid jumps by a fraction of the pitch
  // whenever a spot leaves the detector. Pitch 0: off (single aperture, or no
  // lattice).
  double lattice_pitch_x = 0.0, lattice_pitch_y = 0.0;
  int lattice_columns = 1, lattice_rows = 1;
  LatticeResolve lattice_resolve = LatticeResolve::kCentroid;
  double lattice_spot_radius = 0.03;  // normalized; spots fade out over it at the detector edge
  // Phase from the spots wholly on the detector only (their centres at least
  // two spot radii inside): a spot cut by the edge has its centroid pulled
  // inward by up to its radius, a bias the head cannot tell from the image.
  bool lattice_whole_spot_phase = false;
  // Whole spots read spot by spot (with the whole-spot phase): a spot is whole
  // when none of its lit sites lies on the detector's outermost pixel rows or
  // columns (the baseline's rule: under the on-chip threshold nothing of such a
  // spot is missing, and it keeps more spots than the centre margin), and each
  // weighs by its summed weight over its weighted spread s^2 instead of by its
  // summed weight alone: the noise variance of an intensity-weighted centroid
  // goes as s^2 / sum, and wide_ma's spots differ in spread as much as in
  // brightness. Needs the detector's pixel size (normalized units).
  bool lattice_spotwise_phase = false;
  double lattice_pixel_x = 0.0, lattice_pixel_y = 0.0;
  // Wide fields of view: the physics prior maps the position to the angles
  // through a size x size table of the nominal geometry (refraction, tan)
  // instead of a slope, so the learned terms stay small corrections. 0: slope.
  int geometric_prior_size = 0;
  // The general (geometric) head (model/geometric_head.h): the angles are
  // solved through a differentiable model of the sensor's geometry from the
  // spots the network's site weights read, each site going to the aperture
  // whose spot the geometry puts nearest at the coarse angles (the head
  // above, now the coarse estimate; the true angles while training). The
  // geometry itself is buffers of the model file (geometry.*).
  bool geometric_head = false;
  int geometric_apertures = 0, geometric_groups = 0;  // groups: apertures whose spots overlap read as one
  double geometric_air_above_exit_um = 0.0;           // MaskGeometry::air_above_exit_um (absent in older files: 0)
  double geometric_gate_um = 0.0;                     // sites farther from every spot are not read
  // Whole spots are read at their point of symmetry (baseline/symmetry_centre.h:
  // the sites' weights as the image) instead of their weighted centroid; the
  // noise of the read-out goes as 1 / sum |grad w|^2, not as the spot's spread.
  bool geometric_symmetric_spots = false;
  double detector_pitch_um = 0.0;  // the detector's pixels, to place the sites
  int detector_width_px = 0, detector_height_px = 0;
  double angle_scale_rad = 0.0;  // of the normalized angles (the metadata's)
  // The sub-FOV class reported is the solved angles' (their quadrant, or the
  // aperture whose spot the geometry puts nearest the detector centre), not
  // the classifier's, which only had to be right for the search. From the
  // sensor's sub-FOV scheme (not a metadata key of its own).
  bool geometric_class_by_aperture = false;
  // The pattern head, for masks whose spots merge (a coded mask such as
  // thesis_ca, where no spot can be told apart): the angles, their
  // covariance and the sub-FOV class come from the whole-pattern solve of the
  // sensor's design (baseline/pattern_estimator.h) on the image the sites
  // make; the model's angle correction and sigma level are fitted on held-out
  // images (dss calibrate-sigma). The network is not run: nothing it could
  // weigh enters the solve yet. Needs a sensor that thresholds on chip (the
  // sites are then the whole image) and every lit pixel as a site.
  bool pattern_head = false;
  std::vector<int> head_hidden{256, 256};
  int num_classes = 4;  // sub-FOV classes of the sensor

  bool latticeHead() const { return lattice_pitch_x > 0.0 && lattice_pitch_y > 0.0; }
  // Pitch (normalized) and number of apertures along axis 0 (x, columns) or 1 (y, rows).
  double latticePitch(int axis) const { return axis == 0 ? lattice_pitch_x : lattice_pitch_y; }
  int latticeCount(int axis) const { return axis == 0 ? lattice_columns : lattice_rows; }
  // Normalized distance from the detector edge inside which a spot's centre
  // must lie for the edge not to cut the spot (whole-spot phase, aperture code).
  double wholeSpotMargin() const { return 2.0 * lattice_spot_radius; }
  // The sub-FOV classes are the apertures, and go with the resolved position.
  bool apertureClassLattice() const { return latticeHead() && lattice_resolve != LatticeResolve::kCentroid; }
  // Throws std::invalid_argument naming the bad field.
  void validate() const;
};

// "resnet34" (published layout), "resnet18", "resnet18_w32", "resnet18_w16", "resnet10_w16".
ArchSpec archPreset(const std::string& name, int num_classes);
std::vector<std::string> archPresetNames();
// The same, comma-separated, for help texts and errors.
std::string archPresetList();
// The architecture a model gets when none is named (chosen by dss bench infer/train).
std::string defaultArchName();

}  // namespace dss
