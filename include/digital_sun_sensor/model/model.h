// An SSCNN model: network + metadata, the model file (atomic save, validated
// load) and decoding of network outputs into angles, variances and classes.
//
// File layout: the package's container (common/container.h), magic
// "DSSMODEL", version 2, sections: metadata YAML, weights (torch archive of
// every parameter and buffer by name). Version 1 files (the same bytes with
// the section count field reserved as 0) are still read.
#pragma once

#include <array>
#include <limits>
#include <memory>
#include <opencv2/core.hpp>
#include <optional>
#include <string>
#include <vector>

#include "digital_sun_sensor/common/sun_estimate.h"
#include "digital_sun_sensor/model/metadata.h"
#include "digital_sun_sensor/model/sscnn.h"

namespace dss {

struct SparseSample;

struct Prediction {
  double alpha_rad = 0.0;
  double beta_rad = 0.0;
  double alpha_variance_rad2 = 0.0;
  double beta_variance_rad2 = 0.0;
  int subfov_class = -1;
  double class_probability = 0.0;
  int active_sites = 0;
  // Aperture-code heads: how clearly the spots' sizes chose the aperture
  // (SscnnOutput::code_margin, the least over the mirror images); infinity
  // for other heads.
  double code_margin = std::numeric_limits<double>::infinity();
  // Geometric head: how far the spots lie from the pattern the model's
  // geometry makes, as their weighted residual per degree of freedom over
  // the level calibrated on its sensor (ModelMetadata::mismatch_level): ~1
  // there, large on a unit the geometry does not describe. 0 for other
  // heads, with fewer than two spots read, or before calibration.
  double spot_mismatch = 0.0;
  // Geometric head: one spot read, which another aperture could have made
  // (SscnnOutput::lone_spot_ambiguous, in any of the mirror images).
  bool lone_spot_ambiguous = false;
  // Pattern head: the solve's status where it gives no answer
  // (SscnnOutput::declined); empty where it answers and for other heads.
  std::string declined;
};

struct Model {
  ModelMetadata meta;
  std::shared_ptr<SscnnNetImpl> net;

  // Inference on sensor images (eval mode, no autograd), averaged over the
  // metadata's inference symmetry; in passes of at most 16 network inputs.
  // With `coarse` (one per image), a pattern head chooses between two places
  // its image fits about equally by it (SscnnNetImpl::forward); other heads
  // and models with an inference symmetry refuse it.
  std::vector<Prediction> predict(const std::vector<cv::Mat>& images, const CoarseDirections* coarse = nullptr) const;
  // The same for samples already reduced to their sites (training data), in
  // passes of 64 inputs; no autograd, and the caller chooses train or eval mode.
  std::vector<Prediction> predictSamples(const std::vector<const SparseSample*>& samples) const;
  // Network outputs to angles (the angle correction subtracted), variances and classes.
  std::vector<Prediction> decode(const SscnnOutput& out, const sparse::SiteSet& sites) const;
  // The same with each image's count of active sites.
  std::vector<Prediction> decode(const SscnnOutput& out, const std::vector<int>& counts) const;
  // The metadata's angle correction for the geometry the geometric head
  // holds (a unit's mask height moves it: ModelMetadata::height_corrections).
  UnitAngleCorrection angleCorrection() const;
  // The geometric head's mask height less the design's [um] (0 without one).
  double heightChangeUm() const;
  // Multiplies the predicted standard deviations by these factors (through
  // the variance head's bias; train/sigma_calibration fits them).
  void scaleSigma(double alpha_factor, double beta_factor);
  // Makes the predicted standard deviations these constants (radians) for
  // every image (train/sigma_calibration, when the head's shape is uninformative).
  void setConstantSigma(double alpha_sigma_rad, double beta_sigma_rad);
  // Those constants (radians) when the variance head's weights are all zero,
  // as setConstantSigma (and any scaling after it) leaves them; else nullopt.
  std::optional<std::array<double, 2>> constantSigma() const;
};

// A freshly initialised model for a sensor; seeds torch's generator with `seed`.
Model createModel(const SensorConfig& config, const std::string& arch_name, std::uint64_t seed = 1);
// The same from an architecture spec (a preset with changed options).
Model createModel(const SensorConfig& config, const ArchSpec& arch, std::uint64_t seed = 1,
                  const HeadOptions& head = {});

std::string serializeModel(const Model& model);
void saveModel(const Model& model, const std::string& path);  // atomic (temp file + rename)

// Validates magic, version, lengths, checksum, metadata, architecture and
// every tensor's name and shape; with `expected`, also that it is the sensor
// the model was made for. Throws ModelError naming the file and the problem.
Model loadModel(const std::string& path, const SensorConfig* expected = nullptr);
Model deserializeModel(const std::string& bytes, const std::string& origin, const SensorConfig* expected = nullptr);

}  // namespace dss
