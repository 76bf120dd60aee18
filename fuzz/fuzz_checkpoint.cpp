// Training checkpoints as `dss train --resume` reads them: the bytes go to a
// file and a small trainer resumes from it. The first byte chooses what the
// rest is:
//   0: the whole file (the container's own checks);
//   1: a replacement for one section (next byte: state YAML, model, best
//      model, optimizer state) of a valid checkpoint of the same trainer, so
//      the fuzzer reaches the state reader and the archives behind the checksum.
#include <unistd.h>

#include <atomic>
#include <cstdio>

#include "digital_sun_sensor/common/container.h"
#include "digital_sun_sensor/common/file_io.h"
#include "digital_sun_sensor/common/limits.h"
#include "digital_sun_sensor/model/input_spec.h"
#include "digital_sun_sensor/sim/dataset_generator.h"
#include "digital_sun_sensor/train/trainer.h"
#include "fuzz_entry.h"

namespace {

struct Setup {
  dss::SensorConfig sensor;
  dss::TrainingSet train{dss::InputSpec{}}, validation{dss::InputSpec{}};
  dss::TrainOptions options;
  std::vector<std::string> sections;  // of a valid checkpoint

  Setup() {
    sensor = dss::loadSensorConfig(dss::fuzz::sourceDir() + "/config/sensors/thesis_sa.yaml",
                                   {"optics.psf_node_step_deg=3"});
    dss::TrainingSet all(dss::inputSpecFor(sensor));
    dss::DatasetSpec spec;
    spec.count = 8;
    spec.seed = 5;
    dss::DatasetGenerator(sensor, spec).run([&](const dss::DatasetItem& item) {
      all.add(item.image, item.truth.alpha_rad, item.truth.beta_rad, item.truth.subfov_class);
    });
    train = dss::TrainingSet(all.spec());
    validation = dss::TrainingSet(all.spec());
    all.split(0.25, 1, train, validation);
    options.arch = "resnet10_w16";
    options.batch_size = 4;
    options.epochs = 2;
    options.checkpoint_path = "/tmp/dss_fuzz_valid." + std::to_string(::getpid()) + ".ckpt";
    std::atomic<bool> stop{true};  // a checkpoint at once
    dss::Trainer(sensor, train, validation, options).run({}, stop);
    sections = dss::unpackContainer(dss::readFile(options.checkpoint_path, dss::limits::kMaxCheckpointFileBytes),
                                    "DSSCKPNT", "checkpoint", "valid checkpoint")
                   .sections;
    std::remove(options.checkpoint_path.c_str());
    options.checkpoint_path.clear();
  }
};

// Built before the fuzzer starts: what it allocates once (the renderer's FFT
// plans among it) is not charged to the first input as a leak.
Setup setup;

}  // namespace

extern "C" int DSS_FUZZ_ENTRY(const std::uint8_t* data, std::size_t size) {
  if (size < 2) return 0;
  std::string bytes;
  if (data[0] % 2 == 0) {
    bytes.assign(reinterpret_cast<const char*>(data + 1), size - 1);
  } else {
    std::vector<std::string> sections = setup.sections;
    sections[data[1] % sections.size()].assign(reinterpret_cast<const char*>(data + 2), size - 2);
    bytes = dss::packContainer("DSSCKPNT", 1, sections);
  }
  const std::string path = "/tmp/dss_fuzz_checkpoint." + std::to_string(::getpid()) + ".ckpt";
  dss::writeFileAtomic(path, bytes);
  try {
    dss::Trainer trainer(setup.sensor, setup.train, setup.validation, setup.options);
    trainer.resume(path);
  } catch (const dss::CheckpointError&) {
  }
  std::remove(path.c_str());
  return 0;
}
