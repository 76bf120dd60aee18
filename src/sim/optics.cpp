#include "digital_sun_sensor/sim/optics.h"

#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <complex>
#include <numeric>
#include <sstream>

#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/sim/fft2d.h"
#include "digital_sun_sensor/sim/geometry.h"

namespace dss {
namespace {

constexpr int kCoverageSubsamples = 4;  // per axis, for anti-aliased aperture edges

double sinc(double x) { return std::abs(x) < 1e-9 ? 1.0 : std::sin(x) / x; }

// Fraction of the grid cell centred at (x, y) inside the aperture(s), by supersampling.
template <typename Inside>
float coverage(double x, double y, double step, Inside inside) {
  int hits = 0;
  for (int i = 0; i < kCoverageSubsamples; ++i) {
    const double sy = y + ((i + 0.5) / kCoverageSubsamples - 0.5) * step;
    for (int j = 0; j < kCoverageSubsamples; ++j) {
      const double sx = x + ((j + 0.5) / kCoverageSubsamples - 0.5) * step;
      hits += inside(sx, sy) ? 1 : 0;
    }
  }
  return static_cast<float>(hits) / (kCoverageSubsamples * kCoverageSubsamples);
}

// Multiplies `spectrum` (forward FFT of a real intensity, centre at n/2) by the
// transfer function of the solar disk projected through `jacobian` and/or of
// the pixel box.
void applyDetectorFilters(ComplexGrid& spectrum, const OpticalPath& path, const Eigen::Matrix2d& jacobian,
                          bool sun_disk, bool pixel_box) {
  const int n = spectrum.size();
  const double step = path.step_um;
  if (sun_disk) {
    // Rasterise the limb-darkened disk on the detector grid, centred at index 0
    // (wrapped), normalised to unit sum.
    ComplexGrid kernel(n);
    kernel.fill(0.0f);
    const double radius_rad = 0.5 * degToRad(path.sun.angular_diameter_deg);
    const Eigen::Matrix2d inv = jacobian.inverse();
    const double reach_um = radius_rad * jacobian.norm() + 2.0 * step;
    const int half = std::min(n / 2 - 1, static_cast<int>(std::ceil(reach_um / step)));
    constexpr int kSub = 6;
    double total = 0.0;
    for (int r = -half; r <= half; ++r) {
      for (int c = -half; c <= half; ++c) {
        double acc = 0.0;
        for (int i = 0; i < kSub; ++i) {
          for (int j = 0; j < kSub; ++j) {
            const Eigen::Vector2d u((c + (j + 0.5) / kSub - 0.5) * step, (r + (i + 0.5) / kSub - 0.5) * step);
            const double rho = (inv * u).norm() / radius_rad;
            if (rho < 1.0) acc += 1.0 - path.sun.limb_darkening_u * (1.0 - std::sqrt(1.0 - rho * rho));
          }
        }
        kernel.at((r + n) % n, (c + n) % n) = static_cast<float>(acc);
        total += acc;
      }
    }
    if (total <= 0.0) {
      kernel.at(0, 0) = 1.0f;  // disk smaller than a sample: a point
      total = 1.0;
    }
    const float scale = static_cast<float>(1.0 / total);
    for (int i = 0; i < n * n; ++i) kernel.data()[i] *= scale;
    kernel.forward();
    for (int i = 0; i < n * n; ++i) spectrum.data()[i] *= kernel.data()[i];
  }
  if (pixel_box) {
    std::vector<float> box(n);
    for (int k = 0; k < n; ++k) box[k] = static_cast<float>(sinc(kPi * path.pitch_um * fftFrequency(k, n, step)));
    for (int r = 0; r < n; ++r) {
      for (int c = 0; c < n; ++c) spectrum.at(r, c) *= box[r] * box[c];
    }
  }
}

// Real part of `grid` (already an intensity) into a SpotMap, scaled.
SpotMap toSpotMap(const ComplexGrid& grid, double scale, const OpticalPath& path, bool crop) {
  const int n = grid.size();
  SpotMap map;
  map.step_um = path.step_um;
  std::vector<float> full(static_cast<std::size_t>(n) * n);
  double total = 0.0;
  float peak = 0.0f;
  for (int i = 0; i < n * n; ++i) {
    const float v = static_cast<float>(std::max(0.0, grid.data()[i].real() * scale));
    full[i] = v;
    total += v;
    peak = std::max(peak, v);
  }
  // Power: the map holds per-pixel power sampled every step; a pixel covers pitch^2.
  map.total_power_um2 = total * (path.step_um * path.step_um) / (path.pitch_um * path.pitch_um);
  int r0 = 0, r1 = n - 1, c0 = 0, c1 = n - 1;
  if (crop && peak > 0.0f) {
    const float floor = peak * 1e-6f;
    r0 = n, r1 = -1, c0 = n, c1 = -1;
    for (int r = 0; r < n; ++r) {
      for (int c = 0; c < n; ++c) {
        if (full[static_cast<std::size_t>(r) * n + c] > floor) {
          r0 = std::min(r0, r), r1 = std::max(r1, r), c0 = std::min(c0, c), c1 = std::max(c1, c);
        }
      }
    }
    r0 = std::max(0, r0 - 2), c0 = std::max(0, c0 - 2), r1 = std::min(n - 1, r1 + 2), c1 = std::min(n - 1, c1 + 2);
  }
  map.rows = r1 - r0 + 1;
  map.cols = c1 - c0 + 1;
  map.u0_um = (c0 - n / 2) * path.step_um;
  map.v0_um = (r0 - n / 2) * path.step_um;
  map.values.resize(static_cast<std::size_t>(map.rows) * map.cols);
  for (int r = 0; r < map.rows; ++r) {
    std::copy_n(&full[static_cast<std::size_t>(r + r0) * n + c0], map.cols,
                &map.values[static_cast<std::size_t>(r) * map.cols]);
  }
  return map;
}

GlassSlab glassOf(const OpticalPath& path) { return {path.glass_um, path.glass_index}; }

double fraunhoferShape(const ApertureGeometry& a, double u, double v, double lambda_z) {
  if (a.shape == ApertureShape::kCircle) {
    const double x = kPi * a.diameter_um * std::hypot(u, v) / lambda_z;
    const double j = x < 1e-9 ? 1.0 : 2.0 * std::cyl_bessel_j(1.0, x) / x;
    return j * j;
  }
  const double t = degToRad(a.rotation_deg);
  const double ur = std::cos(t) * u + std::sin(t) * v;
  const double vr = -std::sin(t) * u + std::cos(t) * v;
  const double sx = sinc(kPi * a.width_um * ur / lambda_z);
  const double sy = sinc(kPi * a.height_um * vr / lambda_z);
  return sx * sx * sy * sy;
}

}  // namespace

ApertureGeometry ApertureGeometry::from(const ApertureConfig& a) {
  ApertureGeometry g;
  g.shape = a.shape;
  g.diameter_um = a.diameter_um;
  g.width_um = a.width_um;
  g.height_um = a.height_um;
  g.rotation_deg = a.rotation_deg;
  g.occluders = a.occluders;
  return g;
}

bool ApertureGeometry::contains(double x, double y) const {
  bool inside;
  if (shape == ApertureShape::kCircle) {
    inside = x * x + y * y <= 0.25 * diameter_um * diameter_um;
  } else {
    const double t = degToRad(rotation_deg);
    const double xr = std::cos(t) * x + std::sin(t) * y;
    const double yr = -std::sin(t) * x + std::cos(t) * y;
    inside = std::abs(xr) <= 0.5 * width_um && std::abs(yr) <= 0.5 * height_um;
  }
  if (!inside) return false;
  for (const auto& o : occluders) {
    const double dx = x - o.x_um, dy = y - o.y_um;
    if (dx * dx + dy * dy <= o.radius_um * o.radius_um) return false;
  }
  return true;
}

double ApertureGeometry::nominalAreaUm2() const {
  return shape == ApertureShape::kCircle ? 0.25 * kPi * diameter_um * diameter_um : width_um * height_um;
}

double ApertureGeometry::boundingRadiusUm() const {
  return shape == ApertureShape::kCircle ? 0.5 * diameter_um : 0.5 * std::hypot(width_um, height_um);
}

std::string ApertureGeometry::key() const {
  std::ostringstream s;
  s.precision(6);
  s << static_cast<int>(shape) << ':' << diameter_um << ':' << width_um << ':' << height_um << ':' << rotation_deg;
  for (const auto& o : occluders) s << '|' << o.x_um << ',' << o.y_um << ',' << o.radius_um;
  return s.str();
}

OpticalPath OpticalPath::from(const SensorConfig& c, double height_change_um) {
  OpticalPath p;
  p.mode = c.optics.mode;
  const double height_um = c.mask.height_mm * 1000.0 + height_change_um;
  p.glass_um = c.cover_glass.enabled ? std::min(c.cover_glass.thickness_mm * 1000.0, height_um) : 0.0;
  p.glass_index = c.cover_glass.enabled ? c.cover_glass.refractive_index : 1.0;
  p.air_gap_um = height_um - p.glass_um;
  p.mask_thickness_um = c.mask.thickness_mm * 1000.0;
  p.vignetting = c.optics.vignetting;
  p.wavelengths_um = c.optics.wavelengths_um;
  const double sum = std::accumulate(c.optics.spectral_weights.begin(), c.optics.spectral_weights.end(), 0.0);
  for (double w : c.optics.spectral_weights) p.weights.push_back(w / sum);
  p.sun = c.optics.sun;
  p.pitch_um = c.detector.pitch_um;
  p.step_um = c.optics.grid_step_um;
  p.grid_size = c.optics.grid_size;
  return p;
}

float SpotMap::sample(double u_um, double v_um) const {
  const double x = (u_um - u0_um) / step_um;
  const double y = (v_um - v0_um) / step_um;
  if (!(x >= 0.0 && y >= 0.0 && x < cols - 1 && y < rows - 1)) return 0.0f;
  const int c = static_cast<int>(x), r = static_cast<int>(y);
  const float fx = static_cast<float>(x - c), fy = static_cast<float>(y - r);
  const float* p = &values[static_cast<std::size_t>(r) * cols + c];
  return (1.0f - fy) * ((1.0f - fx) * p[0] + fx * p[1]) + fy * ((1.0f - fx) * p[cols] + fx * p[cols + 1]);
}

double airyIrradiance(double r_um, double diameter_um, double wavelength_um, double distance_um) {
  ApertureGeometry a;
  a.diameter_um = diameter_um;
  const double lambda_z = wavelength_um * distance_um;
  const double amp = a.nominalAreaUm2() / lambda_z;
  return amp * amp * fraunhoferShape(a, r_um, 0.0, lambda_z);
}

SpotMap computeSpotMap(const ApertureGeometry& aperture, const Eigen::Vector3d& sun_mask, const OpticalPath& path,
                       const SpotMapOptions& options) {
  const int n = path.grid_size;
  const double step = path.step_um;
  const Eigen::Vector3d s = sun_mask.normalized();
  const GlassSlab glass = glassOf(path);
  // Geometric centre of the spot relative to the aperture centre.
  const auto hit = traceToDetector(Eigen::Vector3d(0.0, 0.0, path.heightUm()), s, glass);
  const Eigen::Vector2d centre = hit ? *hit : Eigen::Vector2d::Zero();
  const double cos_incidence = std::max(s.z(), 0.0);
  const bool sun = options.sun_disk && path.sun.enabled;
  ComplexGrid field(n);

  if (path.mode == OpticsMode::kFarField) {
    // Published optics: Fraunhofer pattern about the geometric centre.
    const double z = path.air_gap_um + path.glass_um / path.glass_index;
    field.fill(0.0f);
    for (int r = 0; r < n; ++r) {
      for (int c = 0; c < n; ++c) {
        const double u = (c - n / 2) * step, v = (r - n / 2) * step;
        double acc = 0.0;
        for (std::size_t k = 0; k < path.wavelengths_um.size(); ++k) {
          const double lambda_z = path.wavelengths_um[k] * z;
          const double amp = aperture.nominalAreaUm2() / lambda_z;
          acc += path.weights[k] * amp * amp * fraunhoferShape(aperture, u, v, lambda_z);
        }
        field.at(r, c) = static_cast<float>(acc * cos_incidence);
      }
    }
  } else {
    // Vignetting: the beam must pass both faces of the mask; the upper face's
    // opening, seen along the beam, is shifted by t * tan(incidence).
    Eigen::Vector2d shift = Eigen::Vector2d::Zero();
    if (path.vignetting && s.z() > 0.0) shift = path.mask_thickness_um * s.head<2>() / s.z();
    auto inside = [&](double x, double y) {
      return aperture.contains(x, y) && aperture.contains(x + shift.x(), y + shift.y());
    };
    ComplexGrid spectrum(n);
    spectrum.fill(0.0f);
    const double reach = aperture.boundingRadiusUm() + step;
    const int lo = std::max(0, n / 2 - static_cast<int>(std::ceil(reach / step)));
    const int hi = std::min(n - 1, n / 2 + static_cast<int>(std::ceil(reach / step)));
    for (int r = lo; r <= hi; ++r) {
      for (int c = lo; c <= hi; ++c) {
        spectrum.at(r, c) = coverage((c - n / 2) * step, (r - n / 2) * step, step, inside);
      }
    }
    spectrum.forward();

    // Sum of per-wavelength intensities, accumulated in `field` (real part).
    std::vector<double> intensity(static_cast<std::size_t>(n) * n, 0.0);
    const double half_window = 0.5 * n * step - 2.0 * step;
    const double inv_n2 = 1.0 / (static_cast<double>(n) * n);
    for (std::size_t k = 0; k < path.wavelengths_um.size(); ++k) {
      const double lambda = path.wavelengths_um[k];
      const double inv_l2 = 1.0 / (lambda * lambda);
      const double n_inv_l2 = path.glass_index * path.glass_index * inv_l2;
      // Transverse frequency of the incident wave (light travels along -s).
      const double ktx = -s.x() / lambda, kty = -s.y() / lambda;
      for (int r = 0; r < n; ++r) {
        const double gy = fftFrequency(r, n, step);
        const double fy = kty + gy;
        for (int c = 0; c < n; ++c) {
          const double gx = fftFrequency(c, n, step);
          const double fx = ktx + gx;
          const double f2 = fx * fx + fy * fy;
          std::complex<float> value = 0.0f;
          if (f2 < inv_l2) {
            const double kz_air = std::sqrt(inv_l2 - f2);
            const double kz_glass = std::sqrt(n_inv_l2 - f2);
            // Where this component lands relative to the window centre.
            const double slope = path.air_gap_um / kz_air + (path.glass_um > 0.0 ? path.glass_um / kz_glass : 0.0);
            const double land_x = fx * slope - centre.x(), land_y = fy * slope - centre.y();
            if (std::abs(land_x) < half_window && std::abs(land_y) < half_window) {
              const double phase =
                  2.0 * kPi * (path.air_gap_um * kz_air + path.glass_um * kz_glass + gx * centre.x() + gy * centre.y());
              value = spectrum.at(r, c) *
                      std::complex<float>(static_cast<float>(std::cos(phase)), static_cast<float>(std::sin(phase)));
            }
          }
          field.at(r, c) = value;
        }
      }
      field.inverse();
      const double w = path.weights[k] * inv_n2 * inv_n2;
      for (int i = 0; i < n * n; ++i) intensity[i] += w * std::norm(field.data()[i]);
    }
    for (int i = 0; i < n * n; ++i) field.data()[i] = static_cast<float>(intensity[i] * cos_incidence);
  }

  // Field now holds irradiance on the detector plane; filter and integrate.
  const double pixel_area = path.pitch_um * path.pitch_um;
  if (sun || options.pixel_integration) {
    field.forward();
    const Eigen::Matrix2d jac = sun ? sunDiskJacobian(path.heightUm(), s, glass) : Eigen::Matrix2d::Identity();
    applyDetectorFilters(field, path, jac, sun, options.pixel_integration);
    field.inverse();
    return toSpotMap(field, pixel_area / (static_cast<double>(n) * n), path, options.crop);
  }
  return toSpotMap(field, pixel_area, path, options.crop);
}

}  // namespace dss
