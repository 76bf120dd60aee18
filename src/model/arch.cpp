#include "digital_sun_sensor/model/arch.h"

#include <stdexcept>

#include "digital_sun_sensor/common/limits.h"

namespace dss {

const char* centroidWeightingName(CentroidWeighting weighting) {
  switch (weighting) {
    case CentroidWeighting::kValue:
      return "value";
    case CentroidWeighting::kIntensity:
      return "intensity";
    default:
      return "learned";
  }
}

CentroidWeighting parseCentroidWeighting(const std::string& name) {
  for (const auto w : {CentroidWeighting::kLearned, CentroidWeighting::kValue, CentroidWeighting::kIntensity})
    if (name == centroidWeightingName(w)) return w;
  throw std::invalid_argument("centroid weighting must be 'learned', 'value' or 'intensity', not '" + name + "'");
}

void validateHeadChoice(const std::string& head) {
  if (head != "auto" && head != "geometric" && head != "pattern" && head != "classic")
    throw std::invalid_argument("head must be 'auto', 'geometric', 'pattern' or 'classic', not '" + head + "'");
}

std::string headName(const ArchSpec& arch) {
  return arch.geometric_head ? "geometric" : arch.pattern_head ? "pattern" : "classic";
}

void ArchSpec::validate() const {
  auto fail = [&](const std::string& what) { throw std::invalid_argument("architecture '" + name + "': " + what); };
  if (input_channels != 3) fail("input_channels must be 3 (value, x, y)");
  const std::string max_width = std::to_string(limits::kMaxLayerWidth);
  if (stem_width < 1 || stem_width > limits::kMaxLayerWidth) fail("stem_width must be in 1.." + max_width + " (limit)");
  if (stem_kernel < 1 || stem_kernel % 2 == 0 || stem_kernel > limits::kMaxStemKernel)
    fail("stem_kernel must be odd and in 1.." + std::to_string(limits::kMaxStemKernel) + " (limit)");
  if (blocks.empty() || blocks.size() != widths.size()) fail("blocks and widths must be non-empty and of equal length");
  if (blocks.size() > static_cast<std::size_t>(limits::kMaxStages))
    fail("at most " + std::to_string(limits::kMaxStages) + " stages (limit)");
  for (std::size_t i = 0; i < blocks.size(); ++i) {
    if (blocks[i] < 1 || blocks[i] > limits::kMaxBlocksPerStage)
      fail("every stage needs 1.." + std::to_string(limits::kMaxBlocksPerStage) + " blocks (limit)");
    if (widths[i] < 1 || widths[i] > limits::kMaxLayerWidth) fail("widths must be in 1.." + max_width + " (limit)");
  }
  if (centroid_pool && (centroid_width < 1 || centroid_width > limits::kMaxLayerWidth))
    fail("centroid_width must be in 1.." + max_width + " (limit)");
  if (!(residual_scale > 0 && residual_scale <= 1)) fail("residual_scale must be in (0, 1]");
  if (!feature_corrections && !centroid_pool) fail("feature_corrections off needs centroid_pool");
  if (centroid_pool && (centroid_degree < 1 || centroid_degree > 5)) fail("centroid_degree must be in 1..5");
  if (latticeHead()) {
    if (!centroid_pool) fail("the lattice head needs centroid_pool");
    if (lattice_columns < 1 || lattice_rows < 1 || lattice_columns > limits::kMaxLatticeSide ||
        lattice_rows > limits::kMaxLatticeSide)
      fail("lattice_columns and lattice_rows must be in 1.." + std::to_string(limits::kMaxLatticeSide) + " (limit)");
    if (!(lattice_spot_radius > 0.0)) fail("lattice_spot_radius must be positive");
    if (lattice_spotwise_phase && !lattice_whole_spot_phase)
      fail("lattice_spotwise_phase needs lattice_whole_spot_phase");
    if (lattice_spotwise_phase && !(lattice_pixel_x > 0.0 && lattice_pixel_y > 0.0))
      fail("lattice_spotwise_phase needs positive lattice_pixel_x and lattice_pixel_y");
  } else if (lattice_pitch_x < 0.0 || lattice_pitch_y < 0.0) {
    fail("lattice pitches must be positive (or both 0: off)");
  }
  if (geometric_prior_size != 0 && (!centroid_pool || geometric_prior_size < 4 || geometric_prior_size > 1025))
    fail("geometric_prior_size must be 0 or 4..1025, with centroid_pool");
  if (geometric_head) {
    if (!centroid_pool) fail("the geometric head needs centroid_pool");
    if (latticeHead() && lattice_resolve != LatticeResolve::kCode)
      fail("the geometric head keeps a lattice head only as its aperture-code coarse estimate");
    if (geometric_apertures < 1 || geometric_apertures > static_cast<int>(limits::kMaxApertures) ||
        geometric_groups < 1 || geometric_groups > geometric_apertures)
      fail("the geometric head needs geometric_apertures >= 1 and geometric_groups in 1..geometric_apertures");
    if (!(geometric_gate_um > 0.0) || !(detector_pitch_um > 0.0) || detector_width_px < 2 || detector_height_px < 2 ||
        detector_width_px > limits::kMaxDetectorSidePx || detector_height_px > limits::kMaxDetectorSidePx ||
        !(angle_scale_rad > 0.0))
      fail(
          "the geometric head needs a positive geometric_gate_um, detector_pitch_um, detector size and "
          "angle_scale_rad");
  }
  if (pattern_head && (geometric_head || latticeHead() || !(angle_scale_rad > 0.0)))
    fail("the pattern head takes no lattice or geometric head, and needs a positive angle_scale_rad");
  if (head_hidden.size() > static_cast<std::size_t>(limits::kMaxStages))
    fail("at most " + std::to_string(limits::kMaxStages) + " head_hidden layers (limit)");
  for (int h : head_hidden)
    if (h < 1 || h > limits::kMaxLayerWidth) fail("head_hidden sizes must be in 1.." + max_width + " (limit)");
  if (num_classes < 1 || num_classes > static_cast<int>(limits::kMaxApertures))
    fail("num_classes must be in 1.." + std::to_string(limits::kMaxApertures) + " (limit)");
}

ArchSpec archPreset(const std::string& name, int num_classes) {
  ArchSpec a;
  a.name = name;
  a.num_classes = num_classes;
  if (name == "resnet34") {
    // defaults above: the published layout
  } else if (name == "resnet18") {
    a.blocks = {2, 2, 2, 2};
  } else if (name == "resnet18_w32") {
    a.blocks = {2, 2, 2, 2};
    a.stem_width = 32;
    a.widths = {32, 64, 128, 256};
    a.head_hidden = {128, 128};
  } else if (name == "resnet18_w16") {
    a.blocks = {2, 2, 2, 2};
    a.stem_width = 16;
    a.widths = {16, 32, 64, 128};
    a.head_hidden = {64, 64};
  } else if (name == "resnet10_w16") {
    a.blocks = {1, 1, 1, 1};
    a.stem_width = 16;
    a.widths = {16, 32, 64, 128};
    a.head_hidden = {64, 64};
  } else {
    throw std::invalid_argument("unknown architecture '" + name + "' (available: " + archPresetList() + ")");
  }
  a.validate();
  return a;
}

std::vector<std::string> archPresetNames() {
  return {"resnet34", "resnet18", "resnet18_w32", "resnet18_w16", "resnet10_w16"};
}

std::string archPresetList() {
  std::string names;
  for (const auto& n : archPresetNames()) names += (names.empty() ? "" : ", ") + n;
  return names;
}

std::string defaultArchName() { return "resnet18_w32"; }

}  // namespace dss
