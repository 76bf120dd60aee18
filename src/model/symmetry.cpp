#include "digital_sun_sensor/model/symmetry.h"

#include <cmath>
#include <sstream>
#include <stdexcept>
#include <utility>

namespace dss {
namespace {

constexpr double kPositionToleranceUm = 0.05;
constexpr double kSizeToleranceUm = 0.01;
constexpr double kAngleToleranceDeg = 1e-6;

// Difference of two orientations modulo 180 degrees (a rectangle is the same turned half a turn).
double orientationDifferenceDeg(double a_deg, double b_deg) {
  const double d = std::fmod(std::abs(a_deg - b_deg), 180.0);
  return std::min(d, 180.0 - d);
}

bool sameShape(const ApertureConfig& a, const ApertureConfig& b) {
  if (a.shape != b.shape) return false;
  if (a.shape == ApertureShape::kCircle) return std::abs(a.diameter_um - b.diameter_um) < kSizeToleranceUm;
  auto matches = [&](double w, double h, double rotation_deg) {
    return std::abs(w - b.width_um) < kSizeToleranceUm && std::abs(h - b.height_um) < kSizeToleranceUm &&
           orientationDifferenceDeg(rotation_deg, b.rotation_deg) < kAngleToleranceDeg;
  };
  // A w x h rectangle at r is the h x w one at r + 90.
  return matches(a.width_um, a.height_um, a.rotation_deg) || matches(a.height_um, a.width_um, a.rotation_deg + 90.0);
}

// The aperture as the transform mirrors it (positions in the mask frame follow the detector's axes).
ApertureConfig transformed(const ApertureConfig& a, const PixelTransform& t) {
  ApertureConfig out = a;
  if (t.transpose) {
    std::swap(out.x_um, out.y_um);
    out.rotation_deg = 90.0 - out.rotation_deg;  // mirroring about x = y
  }
  if (t.flip_x) {
    out.x_um = -out.x_um;
    out.rotation_deg = -out.rotation_deg;
  }
  if (t.flip_y) {
    out.y_um = -out.y_um;
    out.rotation_deg = -out.rotation_deg;
  }
  return out;
}

}  // namespace

const char* inferenceSymmetryName(InferenceSymmetry symmetry) {
  switch (symmetry) {
    case InferenceSymmetry::kFlips:
      return "flips";
    case InferenceSymmetry::kDihedral:
      return "dihedral";
    case InferenceSymmetry::kNone:
      break;
  }
  return "none";
}

InferenceSymmetry parseInferenceSymmetry(const std::string& name) {
  for (const auto s : {InferenceSymmetry::kNone, InferenceSymmetry::kFlips, InferenceSymmetry::kDihedral})
    if (name == inferenceSymmetryName(s)) return s;
  throw std::invalid_argument("inference symmetry must be 'none', 'flips' or 'dihedral', not '" + name + "'");
}

void PixelTransform::apply(int& x, int& y, int width_px, int height_px) const {
  if (transpose) {
    std::swap(x, y);
    std::swap(width_px, height_px);
  }
  if (flip_x) x = width_px - 1 - x;
  if (flip_y) y = height_px - 1 - y;
}

void PixelTransform::unmapAngles(double& alpha, double& beta) const {
  // A mirror of the detector mirrors the sun's tangents alike, and atan is odd.
  if (flip_x) alpha = -alpha;
  if (flip_y) beta = -beta;
  if (transpose) std::swap(alpha, beta);
}

void PixelTransform::unmapVariances(double& alpha_variance, double& beta_variance) const {
  if (transpose) std::swap(alpha_variance, beta_variance);
}

std::vector<PixelTransform> symmetryTransforms(InferenceSymmetry symmetry) {
  std::vector<PixelTransform> out{{false, false, false}};
  if (symmetry == InferenceSymmetry::kNone) return out;
  out.push_back({false, true, false});
  out.push_back({false, false, true});
  out.push_back({false, true, true});
  if (symmetry == InferenceSymmetry::kFlips) return out;
  for (int k = 0; k < 4; ++k) out.push_back({true, out[k].flip_x, out[k].flip_y});
  return out;
}

std::string symmetryMismatch(const SensorConfig& config, InferenceSymmetry symmetry) {
  if (symmetry == InferenceSymmetry::kDihedral) {
    if (config.detector.width_px != config.detector.height_px)
      return "the detector is not square (" + std::to_string(config.detector.width_px) + " x " +
             std::to_string(config.detector.height_px) + " px)";
    if (std::abs(config.fov.alpha_max_deg - config.fov.beta_max_deg) > 1e-9)
      return "the field of view differs in alpha and beta";
  }
  for (const PixelTransform& t : symmetryTransforms(symmetry)) {
    for (std::size_t i = 0; i < config.mask.apertures.size(); ++i) {
      const ApertureConfig image = transformed(config.mask.apertures[i], t);
      bool found = false;
      for (const ApertureConfig& b : config.mask.apertures)
        found = found || (std::abs(image.x_um - b.x_um) < kPositionToleranceUm &&
                          std::abs(image.y_um - b.y_um) < kPositionToleranceUm && sameShape(image, b));
      if (!found) {
        std::ostringstream o;
        o << "aperture " << i << " at (" << config.mask.apertures[i].x_um << ", " << config.mask.apertures[i].y_um
          << ") um has no counterpart of its shape at its mirror image (" << image.x_um << ", " << image.y_um << ") um";
        return o.str();
      }
    }
  }
  return "";
}

}  // namespace dss
