// The SSCNN as a SunEstimator, behind a torch-free header so that nodes, the
// CLI and evaluation code do not compile libtorch headers.
#pragma once

#include <memory>
#include <string>

#include "digital_sun_sensor/common/sun_estimate.h"
#include "digital_sun_sensor/model/unit_recalibration.h"

namespace dss {

// Aperture-code models (wide_ma): an estimate whose runner-up lattice placement
// scores less than this many times the chosen one's is marked invalid,
// "ambiguous_aperture": the spots' sizes do not tell which apertures they come
// from, and a wrong choice is off by whole lattice pitches (tens of degrees).
constexpr double kMinApertureCodeMargin = 2.5;

class SscnnEstimator : public SunEstimator {
 public:
  // Loads a model file (throws ModelError naming the problem); with
  // `expected`, also checks that it was made for that sensor. Without
  // `mirror_average`, the model's inference symmetry is set aside: each image
  // is estimated alone (EstimatorOptions).
  explicit SscnnEstimator(const std::string& model_path, const SensorConfig* expected = nullptr,
                          bool mirror_average = true);
  ~SscnnEstimator() override;

  std::string source() const override { return "sscnn"; }
  const SensorConfig& sensor() const override;
  // The mirror images averaged per image: "none", "flips" or "dihedral".
  std::string inferenceSymmetry() const;
  // Geometric heads: the spot mismatch beyond which an estimate is flagged
  // model_mismatch (0: not calibrated, never flagged), and the unit
  // calibration the geometry holds (its data; empty: the nominal design).
  double mismatchThreshold() const;
  std::string unitCalibration() const;
  std::vector<SunEstimate> estimate(const std::vector<cv::Mat>& images) override;
  // A pattern head (thesis_ca, no mirror images averaged) chooses by them
  // between two places its image fits about equally; the other heads need
  // none and ignore them.
  std::vector<SunEstimate> estimateWithCoarseDirections(const std::vector<cv::Mat>& images,
                                                        const CoarseDirections& coarse) override;
  void warmUp(int threads) const override;

  // In-flight recalibration (geometric heads; the caller serialises these
  // with estimate()): the network's reading of images with their reference
  // angles, a refit of the model's geometry from a recalibrator's window,
  // the geometry in use, and the model saved atomically with `record` (a
  // YAML map) as its unit calibration.
  bool hasGeometry() const;
  std::vector<UnitImage> readUnit(const std::vector<cv::Mat>& images,
                                  const std::vector<std::array<double, 2>>& reference_rad) const;
  UnitCalibrationReport recalibrate(UnitRecalibrator& recalibrator);
  MaskGeometry geometry() const;
  void saveModel(const std::string& path, const std::string& record) const;

 private:
  std::vector<SunEstimate> estimateWith(const std::vector<cv::Mat>& images, const CoarseDirections* coarse);
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace dss
