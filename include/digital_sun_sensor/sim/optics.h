// Spot formation: scalar diffraction of sunlight through one aperture onto the
// detector, the extended limb-darkened sun, and pixel integration.
//
// Fresnel mode: shifted, band-limited angular-spectrum propagation (Matsushima
// 2009/2010) of the tilted plane wave through the vignetted aperture, through
// an air gap and an optional cover-glass layer, per wavelength. The output
// window is centred on the geometric spot centre, so any incidence angle costs
// the same small FFT; components that would land outside the window are
// dropped instead of wrapping around. Exact scalar theory: no paraxial step.
// Far-field mode: the Fraunhofer (Airy / sinc^2) pattern of the published work.
#pragma once

#include "digital_sun_sensor/sim/sensor_config.h"

#include <Eigen/Core>

#include <vector>

namespace dss {

// What fixes a spot's shape (apart from the incidence direction).
struct ApertureGeometry {
  ApertureShape shape = ApertureShape::kCircle;
  double diameter_um = 0.0;
  double width_um = 0.0;
  double height_um = 0.0;
  double rotation_deg = 0.0;
  std::vector<Occluder> occluders;

  static ApertureGeometry from(const ApertureConfig& a);
  bool contains(double x_um, double y_um) const;  // open and not occluded
  double nominalAreaUm2() const;                  // without occluders
  double boundingRadiusUm() const;
  std::string key() const;  // stable identity for caching
};

// Everything about the optical path that does not change between images.
struct OpticalPath {
  OpticsMode mode = OpticsMode::kFresnel;
  double air_gap_um = 5000.0;  // mask exit face to glass top (or detector)
  double glass_um = 0.0;
  double glass_index = 1.0;
  double mask_thickness_um = 0.0;
  bool vignetting = true;
  std::vector<double> wavelengths_um;
  std::vector<double> weights;  // normalised to sum 1
  SunDiskConfig sun;
  double pitch_um = 1.55;
  double step_um = 1.0;
  int grid_size = 512;

  // The config's path; with `height_change_um`, a built unit's whose mask
  // sits that much higher (an air gap above the glass) or lower (a thinner
  // glass under it): diffraction follows the unit's own path.
  static OpticalPath from(const SensorConfig& config, double height_change_um = 0.0);
  double heightUm() const { return air_gap_um + glass_um; }
};

// Pixel-integrated spot: value(u, v) = power [irradiance-normalised, um^2]
// collected by a pixel whose centre lies at (u, v) from the spot's geometric
// centre, for unit irradiance perpendicular to the sun. Row-major, v rows.
struct SpotMap {
  int cols = 0;
  int rows = 0;
  double step_um = 1.0;
  double u0_um = 0.0;  // position of sample (row 0, col 0)
  double v0_um = 0.0;
  std::vector<float> values;
  double total_power_um2 = 0.0;  // power reaching the detector plane (whole window)

  // Bilinear lookup; zero outside.
  float sample(double u_um, double v_um) const;
};

struct SpotMapOptions {
  bool sun_disk = true;           // convolve with the solar disk (if enabled in the path)
  bool pixel_integration = true;  // box-integrate over one pixel
  bool crop = true;               // keep only the significant region
};

// Spot of one aperture for a unit sun vector in the mask frame (+z up).
SpotMap computeSpotMap(const ApertureGeometry& aperture, const Eigen::Vector3d& sun_mask, const OpticalPath& path,
                       const SpotMapOptions& options = {});

// Fraunhofer irradiance of a circular aperture (unit incident irradiance):
// (A / (lambda z))^2 [2 J1(x) / x]^2, x = pi D r / (lambda z).
double airyIrradiance(double r_um, double diameter_um, double wavelength_um, double distance_um);

}  // namespace dss
