// The SSCNN: a sparse ResNet backbone (strided sparse stem, sparse max pool,
// submanifold residual stages with strided downsampling) and a head that reads
// per-image average and max pooled features plus a learned intensity-weighted
// centroid of the input sites (for a lattice of apertures: the lattice shift,
// see ArchSpec::lattice_pitch_x), and outputs (alpha, beta), a log-variance per
// axis and sub-FOV class logits. Outputs are normalized; Model decodes them.
#pragma once

#include <torch/nn/module.h>
#include <torch/nn/modules/linear.h>
#include <torch/nn/modules/normalization.h>

#include <array>
#include <optional>
#include <tuple>
#include <vector>

#include "digital_sun_sensor/model/arch.h"
#include "digital_sun_sensor/model/geometric_head.h"
#include "digital_sun_sensor/model/input_spec.h"
#include "digital_sun_sensor/model/sparse_layers.h"
#include "digital_sun_sensor/sparse/sparse_tensor.h"

namespace dss {

class PatternEstimator;

// Raw network outputs, normalized units.
struct SscnnOutput {
  torch::Tensor angles;        // [B, 2] (alpha, beta) / angle scale
  torch::Tensor log_variance;  // [B, 2] of the normalized angles
  torch::Tensor class_logits;  // [B, num_classes]
  // Lattice head resolved by the class: the class that goes with the
  // resolved position; geometric head: the solved angles' class; [B]
  // (undefined otherwise: argmax of the logits).
  torch::Tensor resolved_class;
  // Aperture-code lattice head: the runner-up placement's score over the
  // chosen one's, [B] (>= 1; undefined for other heads).
  torch::Tensor code_margin;
  // Geometric head (undefined for other heads): the coarse angles the sites
  // were associated from [B, 2] (normalized; trained on their own loss), the
  // spots read [B] (0: the coarse angles were returned) and their RMS
  // distance from the geometry's spots [B] (um).
  torch::Tensor coarse_angles, spots_read, solve_residual_um;
  // Geometric head: the solve's weighted residual per degree of freedom [B]
  // (GeometricSolution::residual_per_dof), and its inputs, detached: per lit
  // site its position [N, 2] (um from the detector centre, double), weight
  // [N] (double) and image [N] (what a unit calibration fits the geometry to).
  torch::Tensor solve_residual_per_dof, solve_site_um, solve_site_weight, solve_site_image;
  // Geometric head: one spot read that another aperture could have made [B]
  // (bool; GeometricSolution::lone_spot_ambiguous).
  torch::Tensor lone_spot_ambiguous;
  // Geometric head, internal: the output MLP's features [B, F] (detached),
  // read by the variance once the solve is known.
  torch::Tensor head_features;
  // Pattern head: per image the solve's status where it gives no answer
  // (estimate_status.h: no fit, or two places in the field fit alike),
  // empty where it answers; empty vector for other heads.
  std::vector<std::string> declined;
};

class SscnnNetImpl : public torch::nn::Module {
 public:
  explicit SscnnNetImpl(const ArchSpec& arch);
  // `known_classes` [B] (training only): the true sub-FOV classes, which then
  // resolve a class-resolved lattice head (LatticeResolve::kClass) in place
  // of the predicted ones; `known_angles` [B, 2] (training only, normalized):
  // the true angles, from which the geometric head associates the sites in
  // place of the coarse estimate. The pattern head reads `known_angles` [B, 3]
  // as a coarse direction per image (alpha, beta, its sigma; normalized; a
  // row of NaN: none), which chooses between two places its image fits
  // about equally (PatternEstimator::estimateWithCoarseDirections).
  SscnnOutput forward(const sparse::SparseTensor& input, const torch::Tensor& known_classes = {},
                      const torch::Tensor& known_angles = {});
  // The same layers and weights evaluated densely (torch::conv2d over the whole
  // [B, 3, H, W] image), for the sparse-vs-dense benchmark.
  SscnnOutput forwardDense(const torch::Tensor& input);
  const ArchSpec& arch() const { return arch_; }
  // ArchSpec::value_saturation (>= 0): a law of the site weights, no weight
  // depends on it (train/value_saturation_choice picks it on held-out images).
  void setValueSaturation(double saturation) { arch_.value_saturation = saturation; }
  // Physics prior at initialisation: the centroid starts as the plain centre of
  // the active sites and maps linearly to the angles with these slopes
  // (normalized units), so training starts at a pinhole-model estimate.
  void initCentroidMap(double slope_x, double slope_y);
  // Lattice heads whose classes are the apertures: per class, the normalized
  // offset of its aperture's spot from the lattice centre, and the aperture's
  // open area (read by the aperture code). No-op for other heads.
  void initLatticeApertures(const std::vector<std::array<double, 2>>& offsets, const std::vector<double>& areas_um2);
  // Wide fields: the angles of the nominal geometry as a table over the
  // position [2, size, size] (normalized angles) spanning +-extent (normalized
  // position) per axis, read by Catmull-Rom interpolation instead of the linear
  // prior (no-op unless arch.geometric_prior_size > 0).
  void initGeometricPrior(const torch::Tensor& table, double extent_x, double extent_y);
  // A copy of that table and its extents (an undefined table without one).
  std::tuple<torch::Tensor, double, double> geometricPriorCopy() const;
  // Geometric head: the sensor's nominal geometry (no-op for other heads).
  void initGeometry(const GeometryDesign& design);
  // Pattern head: the whole-pattern estimator of the sensor's design (renders
  // its template: seconds for a large mask), and how the sites' values map
  // back to the image's digital numbers (no-op for other heads).
  void initPattern(const SensorConfig& config, const InputSpec& input);
  // Pattern head on the images its sites make (siteImage; no inference
  // symmetry): forward() without the round trip through the sparse tensor.
  // `coarse` as forward()'s known_angles.
  SscnnOutput patternForward(const std::vector<cv::Mat>& images, const torch::Tensor& coarse, torch::Dtype dtype);
  // Pattern head: its design's diffraction cache computed now, on `threads`
  // threads (PatternEstimator::warmUp; no-op for other heads).
  void warmUp(int threads) const;
  // The geometric head's geometry (null for other heads): what a unit
  // calibration fits.
  SensorGeometry geometry() const { return geometry_; }
  // Geometric head: the angles it outputs for solved angles [B, 2]
  // (normalized), the solve plus its learned smooth correction.
  torch::Tensor correctSolvedAngles(const torch::Tensor& solved);
  std::int64_t parameterCount() const;
  // Whether what a prediction publishes (angles, variance, sub-FOV class)
  // reads the backbone's pooled features. Not where the angles are a
  // function of the spot reading alone (no feature corrections, or ones of
  // zero weight; whole pitches from the aperture code or the centroid), the
  // class goes with the resolved position and the variance's weights on the
  // features are zero (a constant sigma): wide_ma's shipped head, whose
  // trained backbone changed no published digit, and the family models'
  // geometric heads as created. Inference (eval mode, no autograd) then skips
  // the backbone unless setSkipUnusedBackbone(false); the class logits are
  // those of zero features (Prediction::class_probability means nothing).
  bool backboneNeeded() const;
  void setSkipUnusedBackbone(bool skip) { skip_unused_backbone_ = skip; }
  // This forward pass would skip the backbone.
  bool skipsBackbone() const;

  // The variance head's level, the sigma interface (model/sigma.cpp): adds to
  // the predicted log variance of the normalized angles, per axis;
  void shiftLogVariance(double alpha, double beta);
  // makes it these constants for every image (the head's weights zeroed);
  void setConstantLogVariance(double alpha, double beta);
  // those constants while the head's weights are all zero, else nullopt.
  std::optional<std::array<double, 2>> constantLogVariance() const;

 private:
  // Spot read-out per image from site weights w [N, 1], positions xy [N, 2],
  // lit [N] (1 for a lit site) and image index [N]: the weighted centroid
  // [B, 2] and, with the lattice head, the phase of the positions modulo the
  // lattice pitch [B, 2] (from the whole spots: lattice_whole_spot_phase)
  // and, with the aperture code, the whole pitches it gives [B, 2] and their
  // margin [B] (CodePlacement), else
  // per axis the contradictions of each candidate placement [B, K]
  // (axisContradictions over latticeSteps).
  struct SpotReading {
    torch::Tensor centroid, phase, code_steps, code_margin;
    std::array<torch::Tensor, 2> contradictions;
  };
  // Site weights of the centroid branch (arch.centroid_weighting) from its
  // output logits (undefined with intensity weights) and the sites' values,
  // [N, 1] each.
  torch::Tensor centroidWeights(const torch::Tensor& logits, const torch::Tensor& value) const;
  SpotReading readSpots(const torch::Tensor& w, const torch::Tensor& xy, const torch::Tensor& lit,
                        const torch::Tensor& index, std::int64_t batch) const;
  // Factors [N, 1] on the site weights w for the phase of the whole spots
  // (arch.lattice_spotwise_phase): 0 on a spot with a lit site on the
  // detector's outermost pixels, else the spot's inverse weighted spread in
  // pixel units. cell: the site's lattice cell around the phase [N, 2].
  torch::Tensor spotwisePhaseFactors(const torch::Tensor& w, const torch::Tensor& xy, const torch::Tensor& lit,
                                     const torch::Tensor& index, const torch::Tensor& cell) const;
  // Lattice shift (position of the lattice centre's spot) [B, 2]: the phase
  // plus the whole pitches the aperture code, the known classes (training),
  // the class probabilities or the coarse centroid imply, first defined first.
  torch::Tensor resolveLattice(const SpotReading& spots, const torch::Tensor& class_logits,
                               const torch::Tensor& known_classes) const;
  // Candidate lattice-centre positions relative to the phase along an axis
  // (whole pitches, plus half a pitch for an even count) [K].
  torch::Tensor latticeSteps(int axis, const torch::TensorOptions& options) const;
  SscnnOutput head(const torch::Tensor& pooled, const SpotReading& spots, const torch::Tensor& known_classes);
  // Geometric head: replaces the head's angles (kept as the coarse ones) by
  // the solve through the geometry from the site weights w [N, 1] at
  // positions xy [N, 2] (normalized), associated from known_angles when
  // given, else from the coarse angles; adds the solve's log variance.
  void solveAngles(SscnnOutput& out, const torch::Tensor& w, const torch::Tensor& xy, const torch::Tensor& index,
                   std::int64_t batch, const torch::Tensor& known_angles);
  // Pattern head: the images the sites make (every lit pixel; zero
  // elsewhere, as the chip's threshold leaves them), each solved whole.
  SscnnOutput patternForward(const sparse::SparseTensor& input, const torch::Tensor& coarse);
  // Normalized angles of the physics prior at a position [B, 2].
  torch::Tensor priorAngles(const torch::Tensor& position) const;
  torch::Tensor monomials(const torch::Tensor& centroid) const;
  ArchSpec arch_;
  std::int64_t pooled_width_ = 0;  // average + max pooled backbone features
  bool skip_unused_backbone_ = true;
  std::shared_ptr<SparseConvImpl> stem_, centroid_conv1_, centroid_conv2_;
  std::vector<std::shared_ptr<ResidualBlockImpl>> blocks_;
  torch::nn::LayerNorm head_norm_{nullptr};
  std::vector<torch::nn::Linear> mlp_;
  torch::nn::Linear output_{nullptr}, variance_{nullptr}, centroid_skip_{nullptr}, class_hidden_{nullptr},
      class_output_{nullptr};
  torch::Tensor centroid_prior_;         // buffer: angle per unit centroid, per axis
  torch::Tensor lattice_class_offsets_;  // buffer [num_classes, 2] (classes are the apertures)
  torch::Tensor lattice_log_area_;       // buffer [rows, columns]: log open area (um^2) per node (aperture code)
  torch::Tensor geometric_prior_, geometric_prior_extent_;  // buffers [1, 2, size, size], [2]
  SensorGeometry geometry_{nullptr};                        // geometric head
  torch::nn::Linear geometric_correction_{nullptr};         // its smooth correction of the solved angles
  std::shared_ptr<const PatternEstimator> pattern_;         // pattern head (initPattern)
  InputSpec pattern_input_;
};

}  // namespace dss
