// Sensor images -> the SSCNN's sparse input batch (features: value, x, y).
#pragma once

#include <vector>

#include "digital_sun_sensor/model/input_spec.h"
#include "digital_sun_sensor/model/symmetry.h"
#include "digital_sun_sensor/sparse/sparse_tensor.h"
#include "digital_sun_sensor/train/training_set.h"

namespace dss {

// Throws std::invalid_argument naming the image (its index) and the problem
// when an image disagrees with the spec.
void checkImages(const std::vector<cv::Mat>& images, const InputSpec& spec);

// Active sites are the pixels above spec.threshold_dn (the brightest
// spec.max_sites per image), in row-major order per image. Coordinates are
// scaled to [-1, 1] across the detector. Checks the images (checkImages). With a
// symmetry, each image becomes consecutive batch entries: its mirror images in
// symmetryTransforms order, the image itself first.
sparse::SparseTensor encodeImages(const std::vector<cv::Mat>& images, const InputSpec& spec,
                                  torch::Dtype dtype = torch::kFloat,
                                  InferenceSymmetry symmetry = InferenceSymmetry::kNone);

// The same encoding of samples whose pixels were extracted already (training).
sparse::SparseTensor encodeSamples(const std::vector<const SparseSample*>& samples, const InputSpec& spec,
                                   InferenceSymmetry symmetry = InferenceSymmetry::kNone);

// The image the active sites make (encodeImages, no symmetry): each site's
// digital number at its pixel, 0 elsewhere, of depth CV_16U where
// spec.max_code > 255, else CV_8U; `sites` is their count. What the pattern
// head solves, without the round trip through the sparse tensor.
cv::Mat siteImage(const cv::Mat& image, const InputSpec& spec, int& sites);

// Dense [batch, 3, H, W] equivalent of encodeImages (zeros at inactive pixels).
torch::Tensor encodeImagesDense(const std::vector<cv::Mat>& images, const InputSpec& spec);

}  // namespace dss
