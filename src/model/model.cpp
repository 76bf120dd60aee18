#include "digital_sun_sensor/model/model.h"

#include <torch/serialize/input-archive.h>
#include <torch/serialize/output-archive.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <optional>
#include <sstream>

#include "digital_sun_sensor/baseline/calibration_model.h"
#include "digital_sun_sensor/common/file_io.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/model/sparse_input.h"
#include "digital_sun_sensor/sim/geometry.h"

namespace dss {
namespace {

constexpr char kMagic[8] = {'D', 'S', 'S', 'M', 'O', 'D', 'E', 'L'};
constexpr std::uint32_t kVersion = 1;
constexpr std::size_t kHeaderBytes = 8 + 4 + 4 + 8 + 8;

template <typename T>
void put(std::string& out, T value) {
  out.append(reinterpret_cast<const char*>(&value), sizeof(T));
}

template <typename T>
T take(const std::string& in, std::size_t offset) {
  T value;
  std::memcpy(&value, in.data() + offset, sizeof(T));
  return value;
}

}  // namespace

namespace {

// d(angle / angle_scale) / d(normalized centroid) per axis of the nominal
// sensor (pinhole + refraction), by central differences at normal incidence.
std::pair<double, double> centroidSlopes(const SensorConfig& config, double angle_scale_rad) {
  const MaskGeometry geometry = MaskGeometry::nominalOf(config);
  const double step_rad = degToRad(0.5);
  auto spot = [&](double alpha, double beta) { return geometry.spotPx(0, sunVectorFromAngles(alpha, beta)); };
  const auto xp = spot(step_rad, 0), xm = spot(-step_rad, 0), yp = spot(0, step_rad), ym = spot(0, -step_rad);
  if (!xp || !xm || !yp || !ym) return {0.0, 0.0};
  const double dx = ((*xp).x() - (*xm).x()) * 2.0 / config.detector.width_px;
  const double dy = ((*yp).y() - (*ym).y()) * 2.0 / config.detector.height_px;
  return {2 * step_rad / angle_scale_rad / dx, 2 * step_rad / angle_scale_rad / dy};
}

// The nominal geometry's angles (normalized) over a grid of lattice-centre
// spot positions spanning the field of view plus 10 %, by inverting the ray
// trace (baseline solveSun) at each node; nodes no ray reaches copy their
// neighbour toward the centre.
struct GeometricPrior {
  torch::Tensor table;  // [2, size, size]
  double extent_x = 1.0, extent_y = 1.0;
};

GeometricPrior geometricPrior(const SensorConfig& config, int size, double angle_scale_rad) {
  MaskGeometry centre = MaskGeometry::nominalOf(config);
  centre.apertures_um = {Eigen::Vector2d::Zero()};
  centre.aperture_diameters_um.resize(1);
  const double half_w = 0.5 * config.detector.width_px, half_h = 0.5 * config.detector.height_px;
  const auto edge_x = centre.spotPx(0, sunVectorFromAngles(1.1 * config.fov.alpha_max_deg * kRadPerDeg, 0.0));
  const auto edge_y = centre.spotPx(0, sunVectorFromAngles(0.0, 1.1 * config.fov.beta_max_deg * kRadPerDeg));
  if (!edge_x || !edge_y) throw ModelError("geometric prior: no ray reaches the detector at the edge of the field");
  GeometricPrior prior;
  prior.extent_x = std::abs(edge_x->x()) / half_w;
  prior.extent_y = std::abs(edge_y->y()) / half_h;
  prior.table = torch::zeros({2, size, size}, torch::kFloat);
  auto t = prior.table.accessor<float, 3>();
  const int mid = size / 2;
  auto node = [&](int k, double extent) { return extent * (2.0 * k / (size - 1) - 1.0); };
  // Centre outward, so that a node no ray reaches has its inner neighbour set.
  std::vector<int> order(static_cast<std::size_t>(size));
  for (int k = 0; k < size; ++k) order[static_cast<std::size_t>(k)] = k;
  std::sort(order.begin(), order.end(), [&](int a, int b) { return std::abs(a - mid) < std::abs(b - mid); });
  for (int row : order)
    for (int col : order) {
      const Eigen::Vector2d px(node(col, prior.extent_x) * half_w, node(row, prior.extent_y) * half_h);
      const SunSolution sun = solveSun(centre, {SpotObservation{0, px}});
      if (sun.ok) {
        t[0][row][col] = static_cast<float>(sun.alpha_rad / angle_scale_rad);
        t[1][row][col] = static_cast<float>(sun.beta_rad / angle_scale_rad);
      } else {
        const int inner_row = row + (row < mid) - (row > mid), inner_col = col + (col < mid) - (col > mid);
        t[0][row][col] = t[0][inner_row][inner_col];
        t[1][row][col] = t[1][inner_row][inner_col];
      }
    }
  return prior;
}

}  // namespace

Model createModel(const SensorConfig& config, const std::string& arch_name, std::uint64_t seed) {
  return createModel(config, archPreset(arch_name, config.numSubFovClasses()), seed);
}

Model createModel(const SensorConfig& config, const ArchSpec& arch, std::uint64_t seed, const HeadOptions& head) {
  torch::manual_seed(seed);
  Model m;
  m.meta = metadataFor(config, arch, head);
  m.net = std::make_shared<SscnnNetImpl>(m.meta.arch);
  const auto [slope_x, slope_y] = centroidSlopes(config, m.meta.angle_scale_rad);
  m.net->initCentroidMap(slope_x, slope_y);
  if (m.meta.arch.geometric_prior_size > 0) {
    const GeometricPrior prior = geometricPrior(config, m.meta.arch.geometric_prior_size, m.meta.angle_scale_rad);
    m.net->initGeometricPrior(prior.table, prior.extent_x, prior.extent_y);
  }
  if (m.meta.arch.apertureClassLattice()) {
    // Classes are the apertures (SubFovType::kNearestAperture), in config order.
    std::vector<std::array<double, 2>> offsets;
    std::vector<double> areas_um2;
    for (const auto& a : config.mask.apertures) {
      offsets.push_back({2.0 * a.x_um / config.detector.pitch_um / config.detector.width_px,
                         2.0 * a.y_um / config.detector.pitch_um / config.detector.height_px});
      areas_um2.push_back(a.areaUm2());
    }
    m.net->initLatticeApertures(offsets, areas_um2);
  }
  // The predicted sigma starts at half a pixel of spot motion, the error of
  // the untrained physics prior, rather than at unit variance ~16 log units
  // above the trained error level (the level is refitted after training
  // anyway: train/sigma_calibration).
  if (slope_x > 0.0 && slope_y > 0.0)
    m.scaleSigma(slope_x / config.detector.width_px, slope_y / config.detector.height_px);
  return m;
}

std::string serializeModel(const Model& model) {
  const std::string meta = metadataToYaml(model.meta);
  torch::serialize::OutputArchive archive;
  for (const auto& p : model.net->named_parameters()) archive.write(p.key(), p.value().detach());
  for (const auto& b : model.net->named_buffers()) archive.write(b.key(), b.value(), /*is_buffer=*/true);
  std::ostringstream weights_stream;
  archive.save_to(weights_stream);
  const std::string weights = weights_stream.str();
  std::string out(kMagic, sizeof(kMagic));
  put<std::uint32_t>(out, kVersion);
  put<std::uint32_t>(out, 0);
  put<std::uint64_t>(out, meta.size());
  put<std::uint64_t>(out, weights.size());
  out += meta;
  out += weights;
  put<std::uint64_t>(out, fnv1a64(out.data(), out.size()));
  return out;
}

void saveModel(const Model& model, const std::string& path) { writeFileAtomic(path, serializeModel(model)); }

Model loadModel(const std::string& path, const SensorConfig* expected) {
  std::string bytes;
  try {
    bytes = readFile(path);
  } catch (const std::runtime_error& e) {
    throw ModelError(std::string("model file: ") + e.what());
  }
  return deserializeModel(bytes, "model file '" + path + "'", expected);
}

Model deserializeModel(const std::string& bytes, const std::string& origin, const SensorConfig* expected) {
  if (bytes.size() < kHeaderBytes + 8 || std::memcmp(bytes.data(), kMagic, sizeof(kMagic)) != 0)
    throw ModelError(origin + ": not a digital_sun_sensor model (bad magic or too short: " +
                     std::to_string(bytes.size()) + " bytes)");
  const auto version = take<std::uint32_t>(bytes, 8);
  if (version != kVersion)
    throw ModelError(origin + ": format version " + std::to_string(version) + " (this build reads " +
                     std::to_string(kVersion) + ")");
  const auto meta_bytes = take<std::uint64_t>(bytes, 16), weight_bytes = take<std::uint64_t>(bytes, 24);
  const std::uint64_t expected_size = kHeaderBytes + meta_bytes + weight_bytes + 8;
  if (meta_bytes > bytes.size() || weight_bytes > bytes.size() || expected_size != bytes.size())
    throw ModelError(origin + ": truncated or padded: " + std::to_string(bytes.size()) + " bytes, header says " +
                     std::to_string(expected_size));
  if (fnv1a64(bytes.data(), bytes.size() - 8) != take<std::uint64_t>(bytes, bytes.size() - 8))
    throw ModelError(origin + ": checksum mismatch (the file is corrupt)");

  Model m;
  m.meta = metadataFromYaml(bytes.substr(kHeaderBytes, meta_bytes), origin);
  if (expected) checkSensorCompatible(m.meta, *expected, origin);
  m.net = std::make_shared<SscnnNetImpl>(m.meta.arch);

  torch::serialize::InputArchive archive;
  try {
    std::istringstream weights(bytes.substr(kHeaderBytes + meta_bytes, weight_bytes));
    archive.load_from(weights);
  } catch (const c10::Error& e) {
    throw ModelError(origin + ": weights are unreadable: " + e.what_without_backtrace());
  }
  torch::NoGradGuard no_grad;
  auto restore = [&](const std::string& name, torch::Tensor& target, bool is_buffer) {
    torch::Tensor stored;
    if (!archive.try_read(name, stored, is_buffer))
      throw ModelError(origin + ": tensor '" + name + "' of architecture '" + m.meta.arch.name + "' is missing");
    if (stored.sizes() != target.sizes() || stored.scalar_type() != target.scalar_type()) {
      std::ostringstream o;
      o << origin << ": tensor '" << name << "' has shape " << stored.sizes() << ", architecture '" << m.meta.arch.name
        << "' needs " << target.sizes();
      throw ModelError(o.str());
    }
    target.copy_(stored);
  };
  for (auto& p : m.net->named_parameters()) restore(p.key(), p.value(), false);
  for (auto& b : m.net->named_buffers()) restore(b.key(), b.value(), true);
  m.net->eval();
  return m;
}

std::vector<Prediction> Model::decode(const SscnnOutput& out, const sparse::SiteSet& sites) const {
  const auto angles = out.angles.detach().to(torch::kDouble).contiguous();
  const auto log_var = out.log_variance.detach().to(torch::kDouble).contiguous();
  const auto probs = torch::softmax(out.class_logits.detach().to(torch::kDouble), 1).contiguous();
  // Accessors, not per-element indexing: each tensor index or item() would allocate.
  const auto a = angles.accessor<double, 2>(), v = log_var.accessor<double, 2>(), c = probs.accessor<double, 2>();
  const auto counts = sites.countsPerImage();
  torch::Tensor resolved_class;
  std::optional<torch::TensorAccessor<std::int64_t, 1>> resolved;
  if (out.resolved_class.defined()) {
    resolved_class = out.resolved_class.to(torch::kLong).contiguous();
    resolved.emplace(resolved_class.accessor<std::int64_t, 1>());
  }
  torch::Tensor code_margin;
  std::optional<torch::TensorAccessor<double, 1>> margin;
  if (out.code_margin.defined()) {
    code_margin = out.code_margin.detach().to(torch::kDouble).contiguous();
    margin.emplace(code_margin.accessor<double, 1>());
  }
  // With an inference symmetry, each image's mirror images are consecutive
  // rows (encodeImages): their angles are mapped back and averaged, the
  // correction fitted to that average is applied to it, and the class is the
  // image's own.
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
    }
    const auto bias = meta.angle_correction.bias(alpha, beta);
    p.alpha_rad = (alpha - bias[0]) * s;
    p.beta_rad = (beta - bias[1]) * s;
    const double site_factor = meta.sigma_site_law.factor(counts[static_cast<std::size_t>(i)]);
    p.alpha_variance_rad2 = alpha_variance * s * s * site_factor * site_factor;
    p.beta_variance_rad2 = beta_variance * s * s * site_factor * site_factor;
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

// predict over `items` in passes of at most `inputs_per_pass` network inputs.
template <typename Item, typename Encode>
std::vector<Prediction> predictInPasses(const Model& model, const std::vector<Item>& items, std::size_t inputs_per_pass,
                                        const Encode& encode) {
  torch::NoGradGuard no_grad;
  const std::size_t per_pass =
      std::max<std::size_t>(1, inputs_per_pass / symmetryTransforms(model.meta.inference_symmetry).size());
  std::vector<Prediction> out;
  out.reserve(items.size());
  for (std::size_t first = 0; first < items.size(); first += per_pass) {
    const std::vector<Item> pass(items.begin() + static_cast<std::ptrdiff_t>(first),
                                 items.begin() + static_cast<std::ptrdiff_t>(std::min(items.size(), first + per_pass)));
    const auto input = encode(pass);
    const std::vector<Prediction> p = model.decode(model.net->forward(input), *input.sites);
    out.insert(out.end(), p.begin(), p.end());
  }
  return out;
}

}  // namespace

std::vector<Prediction> Model::predict(const std::vector<cv::Mat>& images) const {
  checkImages(images, meta.input);  // before the passes, so that errors name the caller's index
  return predictInPasses(*this, images, kImageInputsPerPass, [&](const std::vector<cv::Mat>& pass) {
    return encodeImages(pass, meta.input, torch::kFloat, meta.inference_symmetry);
  });
}

std::vector<Prediction> Model::predictSamples(const std::vector<const SparseSample*>& samples) const {
  return predictInPasses(*this, samples, kSampleInputsPerPass, [&](const std::vector<const SparseSample*>& pass) {
    return encodeSamples(pass, meta.input, meta.inference_symmetry);
  });
}

void Model::scaleSigma(double alpha_factor, double beta_factor) {
  if (!(alpha_factor > 0.0 && beta_factor > 0.0 && std::isfinite(alpha_factor) && std::isfinite(beta_factor)))
    throw std::invalid_argument("scaleSigma: factors must be finite and positive");
  torch::NoGradGuard no_grad;
  for (auto& p : net->named_parameters()) {
    if (p.key() != "variance.bias") continue;
    // log variance + 2 log f = log (f sigma)^2
    p.value()[0] += 2.0 * std::log(alpha_factor);
    p.value()[1] += 2.0 * std::log(beta_factor);
    return;
  }
  throw ModelError("scaleSigma: the network has no variance.bias parameter");
}

void Model::setConstantSigma(double alpha_sigma_rad, double beta_sigma_rad) {
  if (!(alpha_sigma_rad > 0.0 && beta_sigma_rad > 0.0 && std::isfinite(alpha_sigma_rad) &&
        std::isfinite(beta_sigma_rad)))
    throw std::invalid_argument("setConstantSigma: sigmas must be finite and positive");
  torch::NoGradGuard no_grad;
  const double s = meta.angle_scale_rad;
  for (auto& p : net->named_parameters()) {
    if (p.key() == "variance.weight") p.value().zero_();
    if (p.key() == "variance.bias") {
      p.value()[0] = 2.0 * std::log(alpha_sigma_rad / s);  // log variance of the normalized angle
      p.value()[1] = 2.0 * std::log(beta_sigma_rad / s);
    }
  }
}

std::optional<std::array<double, 2>> Model::constantSigma() const {
  torch::Tensor weight, bias;
  for (const auto& p : net->named_parameters()) {
    if (p.key() == "variance.weight") weight = p.value();
    if (p.key() == "variance.bias") bias = p.value();
  }
  if (!weight.defined() || !bias.defined() || weight.count_nonzero().item<std::int64_t>() != 0) return std::nullopt;
  const double s = meta.angle_scale_rad;
  return std::array<double, 2>{s * std::exp(0.5 * bias[0].item<double>()), s * std::exp(0.5 * bias[1].item<double>())};
}

}  // namespace dss
