// Checkpoints: the state a resumed run needs, written and read back.
#include <torch/serialize/input-archive.h>
#include <torch/serialize/output-archive.h>
#include <yaml-cpp/yaml.h>

#include <cmath>
#include <cstring>
#include <sstream>

#include "digital_sun_sensor/common/container.h"
#include "digital_sun_sensor/common/file_io.h"
#include "digital_sun_sensor/common/limits.h"
#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/common/yaml_reader.h"
#include "trainer_impl.h"

namespace dss {
namespace {

// Checkpoints are the package's container (common/container): state YAML,
// current model file, best model file, optimizer state. (Checkpoints of the
// earlier "DSSCKPT1" framing are refused by name: they were made by an older
// build and resume there.)
constexpr char kCheckpointMagic[9] = "DSSCKPNT";
constexpr std::uint32_t kCheckpointVersion = 1;

// Copies every tensor of `to` from the tensor of the same name and shape in
// `from`; a missing or differently shaped one is a CheckpointError.
void copyTensorsByName(const torch::OrderedDict<std::string, torch::Tensor>& from,
                       torch::OrderedDict<std::string, torch::Tensor> to, const std::string& origin) {
  for (auto& item : to) {
    const torch::Tensor* source = from.find(item.key());
    if (!source) throw CheckpointError(origin + ": the checkpoint's model lacks tensor '" + item.key() + "'");
    if (source->sizes() != item.value().sizes())
      throw CheckpointError(origin + ": tensor '" + item.key() + "' has another shape in the checkpoint");
    item.value().copy_(*source);
  }
}

std::vector<std::string> unpackCheckpoint(const std::string& bytes, const std::string& origin) {
  if (bytes.rfind("DSSCKPT1", 0) == 0)
    throw CheckpointError(origin +
                          ": a checkpoint of an older format (DSSCKPT1): resume it with the build that wrote "
                          "it, or start the training afresh");
  Container file;
  try {
    file = unpackContainer(bytes, kCheckpointMagic, "training checkpoint", origin);
  } catch (const ContainerError& e) {
    throw CheckpointError(e.what());
  }
  if (file.version != kCheckpointVersion || file.sections.size() != 4)
    throw CheckpointError(origin + ": checkpoint format version " + std::to_string(file.version) + " with " +
                          std::to_string(file.sections.size()) + " sections (this build reads version " +
                          std::to_string(kCheckpointVersion) + ", 4 sections)");
  return file.sections;
}

}  // namespace

std::uint64_t trainingDataFingerprint(const TrainingSet& set) {
  std::uint64_t h = splitmix64(set.size());
  for (const auto& s : set.samples()) {
    std::uint64_t a, b;
    std::memcpy(&a, &s.alpha_rad, 8);
    std::memcpy(&b, &s.beta_rad, 8);
    h = splitmix64(h ^ a) ^ splitmix64(b + s.pixels.size());
  }
  return h;
}

// `elapsed_s`: training wall time up to now, over every run of this job.
std::string Trainer::Impl::stateYaml(double elapsed_s) const {
  YAML::Emitter e;
  e << YAML::BeginMap;
  e << YAML::Key << "sensor" << YAML::Value << sensor.name;
  e << YAML::Key << "arch" << YAML::Value << options.arch;
  e << YAML::Key << "centroid_weighting" << YAML::Value << options.centroid_weighting;
  e << YAML::Key << "value_saturation" << YAML::Value << std::to_string(options.value_saturation);
  e << YAML::Key << "feature_corrections" << YAML::Value << options.feature_corrections;
  e << YAML::Key << "spot_readout" << YAML::Value << options.spot_readout;
  e << YAML::Key << "lattice_phase" << YAML::Value << options.lattice_phase;
  e << YAML::Key << "head" << YAML::Value << options.head;
  e << YAML::Key << "batch_size" << YAML::Value << options.batch_size;
  e << YAML::Key << "epochs" << YAML::Value << options.epochs;
  e << YAML::Key << "seed" << YAML::Value << options.seed;
  e << YAML::Key << "data_fingerprint" << YAML::Value << data_fingerprint;
  e << YAML::Key << "epoch" << YAML::Value << epoch;
  e << YAML::Key << "step_in_epoch" << YAML::Value << step_in_epoch;
  e << YAML::Key << "elapsed_s" << YAML::Value << elapsed_s;
  e << YAML::Key << "best_val_mean_deg" << YAML::Value << best_val_mean_deg;
  e << YAML::Key << "best_epoch" << YAML::Value << best_epoch;
  // The last validation: what a run resumed after the last epoch reports.
  e << YAML::Key << "last_validation" << YAML::Value << YAML::Load(validationYaml(last));
  e << YAML::EndMap;
  return e.c_str();
}

std::string Trainer::Impl::optimizerBytes() const {
  torch::serialize::OutputArchive archive;
  optimizer->save(archive);
  std::ostringstream stream;
  archive.save_to(stream);
  return stream.str();
}

void Trainer::Impl::saveCheckpoint(const std::string& path, double elapsed_s) const {
  writeFileAtomic(path,
                  packContainer(kCheckpointMagic, kCheckpointVersion,
                                {stateYaml(elapsed_s), serializeModel(model), best_model_bytes, optimizerBytes()}));
}

void Trainer::Impl::resume(const std::string& path) {
  std::string bytes;
  try {
    bytes = readFile(path, limits::kMaxCheckpointFileBytes);
  } catch (const std::runtime_error& e) {
    throw CheckpointError(std::string("checkpoint: ") + e.what());
  }
  const std::string origin = "checkpoint '" + path + "'";
  const auto sections = unpackCheckpoint(bytes, origin);
  YAML::Node state;
  try {
    state = loadYaml(sections[0], origin);
    auto expect = [&](const char* key, const std::string& want) {
      const std::string have = state[key].as<std::string>();
      if (have != want)
        throw CheckpointError(origin + ": made with " + key + " '" + have + "', this run has '" + want + "'");
    };
    expect("sensor", sensor.name);
    expect("arch", options.arch);
    if (state["centroid_weighting"])  // absent in checkpoints made before it existed
      expect("centroid_weighting", options.centroid_weighting);
    if (state["value_saturation"])  // absent in checkpoints made before it existed
      expect("value_saturation", std::to_string(options.value_saturation));
    if (state["feature_corrections"])  // absent in checkpoints made before it existed
      expect("feature_corrections", options.feature_corrections);
    if (state["spot_readout"])  // absent in checkpoints made before it existed
      expect("spot_readout", options.spot_readout);
    if (state["lattice_phase"])  // absent in checkpoints made before it existed
      expect("lattice_phase", options.lattice_phase);
    if (state["head"])  // absent in checkpoints made before it existed
      expect("head", options.head);
    expect("batch_size", std::to_string(options.batch_size));
    expect("epochs", std::to_string(options.epochs));
    expect("seed", std::to_string(options.seed));
    if (state["data_fingerprint"].as<std::uint64_t>() != data_fingerprint)
      throw CheckpointError(origin + ": made from different training data (bags, split or image count differ)");
    epoch = state["epoch"].as<int>();
    step_in_epoch = state["step_in_epoch"].as<std::int64_t>();
    elapsed_before_s = state["elapsed_s"].as<double>();
    best_val_mean_deg = state["best_val_mean_deg"].as<double>();
    best_epoch = state["best_epoch"].as<int>();
    last.best_val_mean_deg = best_val_mean_deg;
    last.best_epoch = best_epoch;
    if (state["last_validation"])  // absent in checkpoints made before it existed
      readValidationYaml(state["last_validation"], last);
    if (epoch < 0 || epoch > options.epochs || step_in_epoch < 0 || !(elapsed_before_s >= 0.0) ||
        !std::isfinite(elapsed_before_s) || best_epoch < -1 || best_epoch > options.epochs)
      throw CheckpointError(origin + ": position out of range (epoch " + std::to_string(epoch) + ", step " +
                            std::to_string(step_in_epoch) + ", best epoch " + std::to_string(best_epoch) + ")");
  } catch (const YAML::Exception& e) {
    throw CheckpointError(origin + ": unreadable state: " + e.what());
  } catch (const YamlError& e) {
    throw CheckpointError(e.what());
  }
  try {
    Model restored = deserializeModel(sections[1], origin, &sensor);
    torch::NoGradGuard no_grad;
    // By name and shape, as a model file is read.
    copyTensorsByName(restored.net->named_parameters(), model.net->named_parameters(), origin);
    copyTensorsByName(restored.net->named_buffers(), model.net->named_buffers(), origin);
    if (!sections[2].empty()) deserializeModel(sections[2], origin + " (its best model)", &sensor);  // readable
    best_model_bytes = sections[2];
    torch::serialize::InputArchive archive;
    std::istringstream stream(sections[3]);
    archive.load_from(stream);
    optimizer->load(archive);
  } catch (const ModelError& e) {
    throw CheckpointError(e.what());
  } catch (const c10::Error& e) {
    throw CheckpointError(origin + ": optimizer state unreadable: " + e.what_without_backtrace());
  }
  model.net->train();
}

}  // namespace dss
