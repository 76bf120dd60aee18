// The model file: "DSSMODEL", version, lengths, metadata YAML, weights (torch
// archive by name), FNV-1a checksum; atomic save, validated load.
#include <torch/serialize/input-archive.h>
#include <torch/serialize/output-archive.h>

#include <cstring>
#include <sstream>

#include "digital_sun_sensor/common/file_io.h"
#include "digital_sun_sensor/model/model.h"

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

}  // namespace dss
