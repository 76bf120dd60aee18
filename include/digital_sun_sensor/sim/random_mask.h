// Seeded irregular masks: aperture lists nobody tuned for, drawn within a
// sensor config (detector, mask height, field of view and readout kept), for
// tests and experiments on the general (geometric) head.
#pragma once

#include <cstdint>
#include <string>

#include "digital_sun_sensor/sim/sensor_config.h"

namespace dss {

struct RandomMaskOptions {
  int apertures = 5;  // 1..64
  // Aperture diameter [um]; 0 keeps the base config's first aperture's
  // (or its rectangle's equivalent circle).
  double diameter_um = 0.0;
  // Diameters drawn uniformly within +-this fraction of diameter_um (0: all
  // alike). Spots of different sizes differ in peak irradiance (a Fresnel
  // ring or a bright core), and a threshold relative to the brightest pixel
  // may leave only the brightest: see min_lit_spots.
  double diameter_spread = 0.0;
  // Spot centres at least this many spot diameters apart (spots that can be
  // told apart; the spot diameter is the aperture's plus its diffraction and
  // the solar disk's blur at the mask height).
  double min_separation_spots = 2.5;
  // At every attitude of the field (checked on a grid), at least this many
  // spots lie wholly on the detector.
  int min_whole_spots = 2;
  // At every attitude of a coarser grid, at least this many whole spots
  // show light in the design's noise-free, thresholded image (rendered:
  // seconds per draw checked). 0: not checked.
  int min_lit_spots = 0;
};

struct RandomMask {
  SensorConfig config;  // the base with the drawn apertures and a new name
  double spot_diameter_um = 0.0;
  double min_spacing_um = 0.0;
  int min_whole_spots = 0;  // fewest whole spots over the field's grid
  int min_lit_spots = -1;   // fewest lit whole spots over the rendered grid (-1: not checked)
  int draws = 0;            // masks drawn until one met the options
};

// Draws aperture positions uniformly over the area whose spots can reach the
// detector, keeping the first mask that meets the options. Deterministic for
// a seed. Throws std::invalid_argument naming the option that cannot be met
// (after 20 000 draws: too many apertures for the detector, a field too wide).
RandomMask drawRandomMask(const SensorConfig& base, const RandomMaskOptions& options, std::uint64_t seed,
                          const std::string& name = "");

// Estimated diameter of one aperture's spot on the detector [um]: the
// aperture, the first diffraction ring at the mean wavelength and the solar
// disk's image at the mask height.
double spotDiameterUm(const SensorConfig& config, double aperture_diameter_um);

}  // namespace dss
