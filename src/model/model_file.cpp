// The model file: the package's container (magic "DSSMODEL", version 2) with
// two sections, the metadata YAML and the weights (torch archive by name);
// atomic save, validated load.
#include <torch/serialize/input-archive.h>
#include <torch/serialize/output-archive.h>

#include <sstream>

#include "digital_sun_sensor/common/container.h"
#include "digital_sun_sensor/common/file_io.h"
#include "digital_sun_sensor/common/limits.h"
#include "digital_sun_sensor/model/geometry_design.h"
#include "digital_sun_sensor/model/model.h"

namespace dss {
namespace {

constexpr char kMagic[9] = "DSSMODEL";
// 2: the package's container (common/container); 1: the same bytes for two
// sections with the section count field reserved as 0 (still read).
constexpr std::uint32_t kVersion = 2;
constexpr std::uint32_t kLegacyVersion = 1;

}  // namespace

std::string serializeModel(const Model& model) {
  const std::string meta = metadataToYaml(model.meta);
  torch::serialize::OutputArchive archive;
  for (const auto& p : model.net->named_parameters()) archive.write(p.key(), p.value().detach());
  for (const auto& b : model.net->named_buffers()) archive.write(b.key(), b.value(), /*is_buffer=*/true);
  std::ostringstream weights_stream;
  archive.save_to(weights_stream);
  return packContainer(kMagic, kVersion, {meta, weights_stream.str()});
}

void saveModel(const Model& model, const std::string& path) { writeFileAtomic(path, serializeModel(model)); }

Model loadModel(const std::string& path, const SensorConfig* expected) {
  std::string bytes;
  try {
    bytes = readFile(path, limits::kMaxModelFileBytes);
  } catch (const std::runtime_error& e) {
    throw ModelError(std::string("model file: ") + e.what());
  }
  return deserializeModel(bytes, "model file '" + path + "'", expected);
}

Model deserializeModel(const std::string& bytes, const std::string& origin, const SensorConfig* expected) {
  Container file;
  try {
    file = unpackContainer(bytes, kMagic, "model", origin, /*legacy_sections=*/2);
  } catch (const ContainerError& e) {
    throw ModelError(e.what());
  }
  if ((file.version != kVersion && file.version != kLegacyVersion) || file.sections.size() != 2)
    throw ModelError(origin + ": format version " + std::to_string(file.version) + " with " +
                     std::to_string(file.sections.size()) +
                     " sections (this build reads versions 1 and 2, 2 sections)");
  const std::string& metadata = file.sections[0];
  const std::string& weight_bytes = file.sections[1];

  Model m;
  m.meta = metadataFromYaml(metadata, origin);
  if (expected) checkSensorCompatible(m.meta, *expected, origin);
  m.net = std::make_shared<SscnnNetImpl>(m.meta.arch);

  torch::serialize::InputArchive archive;
  try {
    std::istringstream weights(weight_bytes);
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
  if (m.net->geometry()) {  // the tensors may hold a unit: the corrections were fitted on the design
    try {
      m.net->geometry()->setDesignHeight(
          geometryDesignOf(parseSensorConfig(m.meta.sensor_yaml, origin + " (embedded sensor config)")));
    } catch (const std::exception& e) {
      throw ModelError(origin + ": no geometric design from the embedded sensor config: " + e.what());
    }
    try {
      m.net->geometry()->setPositionVariance(m.meta.aperture_variance_um2, m.meta.spot_noise_um2);
    } catch (const std::invalid_argument& e) {
      throw ModelError(origin + ": metadata key 'aperture_position': " + e.what());
    }
    try {
      m.net->geometry()->setSpotBias(m.meta.spot_bias);
    } catch (const std::invalid_argument& e) {
      throw ModelError(origin + ": metadata key 'spot_bias': " + e.what());
    }
  }
  if (m.meta.arch.pattern_head) {
    try {
      m.net->initPattern(parseSensorConfig(m.meta.sensor_yaml, origin + " (embedded sensor config)"), m.meta.input);
    } catch (const std::exception& e) {
      throw ModelError(origin + ": no pattern estimator from the embedded sensor config: " + e.what());
    }
  }
  m.net->eval();
  return m;
}

}  // namespace dss
