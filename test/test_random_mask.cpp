// Seeded irregular masks (sim/random_mask.h): the lit-spot check.
#include <gtest/gtest.h>

#include <stdexcept>

#include "digital_sun_sensor/sim/random_mask.h"

namespace dss {
namespace {

// Three apertures under a 70 % threshold (docs/results/irregular_masks.md,
// masks D and F), coarse diffraction nodes for speed.
SensorConfig threeApertureBase() {
  return loadSensorConfig(std::string(DSS_SOURCE_DIR) + "/config/sensors/thesis_sa.yaml",
                          {"optics.psf_node_step_deg=3", "detector.width_px=640", "detector.height_px=480",
                           "detector.pitch_um=3.0", "mask.height_mm=3.0", "detector_noise.bit_depth=12",
                           "threshold.level_fraction=0.7", "fov.alpha_max_deg=9", "fov.beta_max_deg=9"});
}

RandomMaskOptions threeApertures() {
  RandomMaskOptions options;
  options.apertures = 3;
  options.diameter_um = 110.0;
  options.min_whole_spots = 2;
  return options;
}

// Apertures alike keep both whole spots lit; apertures of different sizes
// (mask D) keep two whole spots on the detector, of which the relative
// threshold leaves one lit over part of the field. Checking does not change
// the draw.
TEST(RandomMask, LitSpotsAreCountedInTheDesignsThresholdedImages) {
  RandomMaskOptions alike = threeApertures();
  const RandomMask unchecked = drawRandomMask(threeApertureBase(), alike, 43);
  EXPECT_EQ(unchecked.min_lit_spots, -1);
  alike.min_lit_spots = 2;
  const RandomMask checked = drawRandomMask(threeApertureBase(), alike, 43);
  EXPECT_EQ(checked.min_lit_spots, 2);
  EXPECT_EQ(checked.draws, unchecked.draws);
  EXPECT_EQ(checked.config.mask.apertures.size(), 3u);

  RandomMaskOptions sized = threeApertures();
  sized.diameter_spread = 0.3;
  sized.min_lit_spots = 1;
  const RandomMask d = drawRandomMask(threeApertureBase(), sized, 41);
  EXPECT_GE(d.min_whole_spots, 2);
  EXPECT_EQ(d.min_lit_spots, 1);

  sized.min_lit_spots = 3;  // more than the whole spots asked for
  try {
    drawRandomMask(threeApertureBase(), sized, 41);
    FAIL() << "min_lit_spots above min_whole_spots accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("min_lit_spots"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace dss
