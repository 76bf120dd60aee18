// Inference over the sensor's mirror symmetries: a network is not exactly
// equivariant to them, so its estimates of an image and of its mirror images
// differ by more than the image's noise explains. Averaging the estimates over
// the group (each mapped back) makes the estimator exactly equivariant and
// averages out the part of the network's error the mirror images do not share.
// Torch-free.
#pragma once

#include <string>
#include <vector>

#include "digital_sun_sensor/sim/sensor_config.h"

namespace dss {

// kNone: the image as it is. kFlips: also mirrored in x, in y, and in both
// (4 images). kDihedral: those and their transposes (8 images; square
// detectors whose design is the same with x and y swapped).
enum class InferenceSymmetry { kNone, kFlips, kDihedral };
const char* inferenceSymmetryName(InferenceSymmetry symmetry);
// Throws std::invalid_argument for a name other than none, flips or dihedral.
InferenceSymmetry parseInferenceSymmetry(const std::string& name);

// One element of the group on pixel coordinates: transpose first (x <-> y),
// then mirror x -> width-1-x and/or y -> height-1-y.
struct PixelTransform {
  bool transpose = false;
  bool flip_x = false;
  bool flip_y = false;

  // A pixel's position in the transformed image (width and height of the original).
  void apply(int& x, int& y, int width_px, int height_px) const;
  // Angles (or any per-axis pair that follows x and y, tan-odd like the
  // angles) read from the transformed image, mapped back to the original's.
  void unmapAngles(double& alpha, double& beta) const;
  // Per-axis variances read from the transformed image, back to the original's axes.
  void unmapVariances(double& alpha_variance, double& beta_variance) const;
};

// The group's transforms, the identity first.
std::vector<PixelTransform> symmetryTransforms(InferenceSymmetry symmetry);

// Empty when the sensor's design (detector, aperture layout and shapes, field
// of view) is unchanged by every transform of the group; else why not, naming
// what breaks it. (Noise, anomalies and as-built errors are drawn from
// distributions the mirrors leave unchanged.)
std::string symmetryMismatch(const SensorConfig& config, InferenceSymmetry symmetry);

}  // namespace dss
