// SSCNN architectures: the published SparseResNet34 layout and lighter
// variants. Torch-free: the spec travels in model-file metadata.
#pragma once

#include <string>
#include <vector>

namespace dss {

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
  int centroid_degree = 3;    // the angles get a learned polynomial of the centroid (degree 1..this)
  // Learned angle terms are multiplied by this (normalized units): on top of the
  // physics prior they are corrections, and Adam's per-step change of a weight
  // is about the learning rate whatever the gradient's size, so their scale
  // sets the finest step the optimizer takes on the angles.
  double residual_scale = 0.02;
  std::vector<int> head_hidden{256, 256};
  int num_classes = 4;  // sub-FOV classes of the sensor

  // Throws std::invalid_argument naming the bad field.
  void validate() const;
};

// "resnet34" (published layout), "resnet18", "resnet18_w32", "resnet10_w16".
ArchSpec archPreset(const std::string& name, int num_classes);
std::vector<std::string> archPresetNames();
// The architecture a model gets when none is named (chosen by dss bench infer/train).
std::string defaultArchName();

}  // namespace dss
