// Network outputs to angles, variances and classes, and inference in passes.
#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/model/sparse_input.h"

namespace dss {

std::vector<Prediction> Model::decode(const SscnnOutput& out, const sparse::SiteSet& sites) const {
  return decode(out, sites.countsPerImage());
}

std::vector<Prediction> Model::decode(const SscnnOutput& out, const std::vector<int>& counts) const {
  const auto angles = out.angles.detach().to(torch::kDouble).contiguous();
  const auto log_var = out.log_variance.detach().to(torch::kDouble).contiguous();
  const auto probs = torch::softmax(out.class_logits.detach().to(torch::kDouble), 1).contiguous();
  // Accessors, not per-element indexing: each tensor index or item() would allocate.
  const auto a = angles.accessor<double, 2>(), v = log_var.accessor<double, 2>(), c = probs.accessor<double, 2>();
  torch::Tensor resolved_class;
  std::optional<torch::TensorAccessor<std::int64_t, 1>> resolved;
  if (out.resolved_class.defined()) {
    resolved_class = out.resolved_class.to(torch::kLong).contiguous();
    resolved.emplace(resolved_class.accessor<std::int64_t, 1>());
  }
  torch::Tensor code_margin, residual_per_dof;
  std::optional<torch::TensorAccessor<double, 1>> margin, residual;
  if (out.solve_residual_per_dof.defined() && meta.mismatch_level > 0.0) {
    residual_per_dof = out.solve_residual_per_dof.detach().to(torch::kDouble).contiguous();
    residual.emplace(residual_per_dof.accessor<double, 1>());
  }
  if (out.code_margin.defined()) {
    code_margin = out.code_margin.detach().to(torch::kDouble).contiguous();
    margin.emplace(code_margin.accessor<double, 1>());
  }
  torch::Tensor lone_spot;
  std::optional<torch::TensorAccessor<bool, 1>> lone;
  if (out.lone_spot_ambiguous.defined()) {
    lone_spot = out.lone_spot_ambiguous.to(torch::kBool).contiguous();
    lone.emplace(lone_spot.accessor<bool, 1>());
  }
  // With an inference symmetry, each image's mirror images are consecutive
  // rows (encodeImages): their angles are mapped back and averaged, the
  // correction fitted to that average is applied to it, and the class is the
  // image's own.
  const UnitAngleCorrection correction = angleCorrection();
  const std::vector<PixelTransform> transforms = symmetryTransforms(meta.inference_symmetry);
  const auto group = static_cast<std::int64_t>(transforms.size());
  if (angles.size(0) % group != 0)
    throw std::invalid_argument("decode: " + std::to_string(angles.size(0)) + " outputs are not whole groups of " +
                                std::to_string(group) + " mirror images");
  const double s = meta.angle_scale_rad;
  std::vector<Prediction> result(static_cast<std::size_t>(angles.size(0) / group));
  for (std::size_t b = 0; b < result.size(); ++b) {
    Prediction& p = result[b];
    const auto i = static_cast<std::int64_t>(b) * group;
    double alpha = 0.0, beta = 0.0, alpha_variance = 0.0, beta_variance = 0.0;
    for (std::int64_t g = 0; g < group; ++g) {
      double ga = a[i + g][0], gb = a[i + g][1], gva = std::exp(v[i + g][0]), gvb = std::exp(v[i + g][1]);
      transforms[static_cast<std::size_t>(g)].unmapAngles(ga, gb);
      transforms[static_cast<std::size_t>(g)].unmapVariances(gva, gvb);
      alpha += ga / group;
      beta += gb / group;
      alpha_variance += gva / group;
      beta_variance += gvb / group;
      if (margin) p.code_margin = std::min(p.code_margin, (*margin)[i + g]);
      if (lone) p.lone_spot_ambiguous = p.lone_spot_ambiguous || (*lone)[i + g];
      if (residual) p.spot_mismatch = std::max(p.spot_mismatch, (*residual)[i + g] / meta.mismatch_level);
    }
    const auto bias = correction.bias(alpha, beta);
    p.alpha_rad = (alpha - bias[0]) * s;
    p.beta_rad = (beta - bias[1]) * s;
    const double site_factor = meta.sigma_site_law.factor(counts[static_cast<std::size_t>(i)]);
    p.alpha_variance_rad2 =
        alpha_variance * s * s * site_factor * site_factor + meta.geometry_sigma_rad[0] * meta.geometry_sigma_rad[0];
    p.beta_variance_rad2 =
        beta_variance * s * s * site_factor * site_factor + meta.geometry_sigma_rad[1] * meta.geometry_sigma_rad[1];
    for (std::int64_t k = 0; k < probs.size(1); ++k)
      if (k == 0 || c[i][k] > p.class_probability) {
        p.subfov_class = static_cast<int>(k);
        p.class_probability = c[i][k];
      }
    if (resolved) {
      p.subfov_class = static_cast<int>((*resolved)[i]);
      p.class_probability = c[i][(*resolved)[i]];
    }
    p.active_sites = counts[static_cast<std::size_t>(i)];
    if (!out.declined.empty()) p.declined = out.declined[static_cast<std::size_t>(i)];
  }
  return result;
}

namespace {

// Network inputs (images times their mirror images) per forward pass. Larger
// batches ran slower per image here, the rulebooks and gathers outgrowing the
// caches (thesis_sa_t50, 8 mirror images each: 5.6 ms per image at 16 inputs,
// 18 ms at 128; single images 1.03 ms at 16, 1.43 ms at 64).
constexpr std::size_t kImageInputsPerPass = 16;
// Training samples as before the symmetry: 64 per pass when it is none.
constexpr std::size_t kSampleInputsPerPass = 64;

// The coarse directions of items [first, first + count) as the pattern
// head reads them (SscnnNetImpl::forward's known_angles); undefined without.
torch::Tensor coarseInput(const Model& model, const CoarseDirections* coarse, std::size_t first, std::size_t count) {
  if (!coarse) return {};
  const double s = model.meta.angle_scale_rad, none = std::numeric_limits<double>::quiet_NaN();
  torch::Tensor known = torch::full({static_cast<std::int64_t>(count), 3}, none, torch::kDouble);
  for (std::size_t k = 0; k < count; ++k)
    if (const auto& c = (*coarse)[first + k]) {
      known[static_cast<std::int64_t>(k)][0] = c->alpha_rad / s;
      known[static_cast<std::int64_t>(k)][1] = c->beta_rad / s;
      known[static_cast<std::int64_t>(k)][2] = c->sigma_rad / s;
    }
  return known;
}

// predict over `items` in passes of at most `inputs_per_pass` network inputs.
// With `coarse` (one per item, no inference symmetry), the pattern head's coarse directions.
template <typename Item, typename Encode>
std::vector<Prediction> predictInPasses(const Model& model, const std::vector<Item>& items, std::size_t inputs_per_pass,
                                        const Encode& encode, const CoarseDirections* coarse = nullptr) {
  torch::NoGradGuard no_grad;
  const std::size_t per_pass =
      std::max<std::size_t>(1, inputs_per_pass / symmetryTransforms(model.meta.inference_symmetry).size());
  std::vector<Prediction> out;
  out.reserve(items.size());
  for (std::size_t first = 0; first < items.size(); first += per_pass) {
    const std::vector<Item> pass(items.begin() + static_cast<std::ptrdiff_t>(first),
                                 items.begin() + static_cast<std::ptrdiff_t>(std::min(items.size(), first + per_pass)));
    const auto input = encode(pass);
    const torch::Tensor known = coarseInput(model, coarse, first, pass.size());
    const std::vector<Prediction> p = model.decode(model.net->forward(input, {}, known), *input.sites);
    out.insert(out.end(), p.begin(), p.end());
  }
  return out;
}

}  // namespace

std::vector<Prediction> Model::predict(const std::vector<cv::Mat>& images, const CoarseDirections* coarse) const {
  checkImages(images, meta.input);  // before the passes, so that errors name the caller's index
  if (coarse) {
    if (!meta.arch.pattern_head)
      throw std::invalid_argument("predict: only a pattern head takes coarse directions (its pattern repeats)");
    if (symmetryTransforms(meta.inference_symmetry).size() != 1)
      throw std::invalid_argument("predict: coarse directions need the inference symmetry 'none'");
    if (coarse->size() != images.size())
      throw std::invalid_argument("predict: " + std::to_string(coarse->size()) + " coarse directions for " +
                                  std::to_string(images.size()) + " images");
  }
  if (meta.arch.pattern_head && symmetryTransforms(meta.inference_symmetry).size() == 1) {
    // The pattern head solves the image its sites make: made directly, the
    // same images and answers as through the sparse tensor, without it.
    torch::NoGradGuard no_grad;
    std::vector<cv::Mat> site_images;
    std::vector<int> counts(images.size(), 0);
    for (std::size_t k = 0; k < images.size(); ++k) site_images.push_back(siteImage(images[k], meta.input, counts[k]));
    return decode(net->patternForward(site_images, coarseInput(*this, coarse, 0, images.size()), torch::kFloat),
                  counts);
  }
  return predictInPasses(
      *this, images, kImageInputsPerPass,
      [&](const std::vector<cv::Mat>& pass) {
        return encodeImages(pass, meta.input, torch::kFloat, meta.inference_symmetry);
      },
      coarse);
}

std::vector<Prediction> Model::predictSamples(const std::vector<const SparseSample*>& samples) const {
  return predictInPasses(*this, samples, kSampleInputsPerPass, [&](const std::vector<const SparseSample*>& pass) {
    return encodeSamples(pass, meta.input, meta.inference_symmetry);
  });
}

double Model::heightChangeUm() const {
  const SensorGeometry geometry = net->geometry();
  if (!geometry || !geometry->designHeightUm()) return 0.0;
  return geometry->height_um.item<double>() - *geometry->designHeightUm();
}

UnitAngleCorrection Model::angleCorrection() const {
  return {meta.angle_correction, meta.height_corrections, meta.height_corrections.empty() ? 0.0 : heightChangeUm()};
}

}  // namespace dss
