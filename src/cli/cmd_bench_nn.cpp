// dss bench infer | train: SSCNN speed, sparse vs the same network run densely.
#include <torch/optim/adamw.h>

#include <algorithm>
#include <chrono>
#include <ctime>
#include <iostream>
#include <numeric>
#include <thread>

#include "commands.h"
#include "digital_sun_sensor/common/statistics.h"
#include "digital_sun_sensor/estimate/estimator_factory.h"
#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/model/sparse_input.h"
#include "digital_sun_sensor/sim/dataset_generator.h"
#include "digital_sun_sensor/sparse/threads.h"
#include "digital_sun_sensor/train/loss.h"
#include "digital_sun_sensor/train/trainer.h"
#include "progress.h"

namespace dss::cli {
namespace {

using Clock = std::chrono::steady_clock;

double msSince(Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); }

// The calling thread's CPU time [ms]: beside the wall clock, what a shared
// machine's other work does not add (the sparse run computes on this thread).
double threadCpuMs() {
  timespec t{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return t.tv_sec * 1e3 + t.tv_nsec * 1e-6;
}

std::vector<OptionSpec> nnBenchOptions(const std::string& blas_threads) {
  auto specs = sensorOptions();
  specs.insert(specs.end(),
               {
                   {"arch", "A", "architecture (" + archPresetList() + ")", defaultArchName(), false, false},
                   {"model", "FILE", "time this model file instead of a fresh --arch network", "", false, false},
                   {"seed", "S", "seed of the simulated images and the weights", "1", false, false},
                   {"aten-threads", "N", "ATen (OpenMP) threads", "1", false, false},
                   {"blas-threads", "N", "OpenBLAS threads (sparse convolution GEMMs)", blas_threads, false, false},
               });
  return specs;
}

Model benchModel(const Args& args, const SensorConfig& config) {
  if (args.has("model")) return loadModel(args.get("model"), &config);
  return createModel(config, args.get("arch"), static_cast<std::uint64_t>(args.getInt("seed")));
}

std::vector<DatasetItem> simulate(const SensorConfig& config, std::uint64_t count, std::uint64_t seed) {
  DatasetSpec spec;
  spec.count = count;
  spec.seed = seed;
  spec.threads = 2;
  std::vector<DatasetItem> items;
  Progress progress("simulating " + std::to_string(count) + " images", count);
  DatasetGenerator(config, spec)
      .run([&](const DatasetItem& i) { items.push_back(i); },
           [&](std::uint64_t done, std::uint64_t) { progress.update(done); });
  progress.finish();
  return items;
}

}  // namespace

int runBenchInfer(int argc, char** argv) {
  auto specs = nnBenchOptions("1");  // measured: single-image GEMMs are too small to split
  specs.insert(specs.end(),
               {
                   {"count", "N", "images timed through the sparse network", "200", false, false},
                   {"images", "N", "distinct simulated images, cycled (default: --count)", "", false, false},
                   {"dense-count", "N", "images timed through the dense network", "5", false, false},
                   {"symmetry", "S",
                    "--model: 'model' (average over the mirror images its file names) or 'none' (the image alone; "
                    "calibration_node's ~inference_symmetry)",
                    "model", false, false},
                   {"dense-aten-threads", "N",
                    "ATen threads of the dense run (its convolutions are ATen's; OpenBLAS gets 1)", "2", false, false},
               });
  Args args("dss bench infer",
            "Single-image SSCNN inference time (image -> sites -> rulebooks -> network -> angles), sparse and the "
            "same layers and weights run densely (torch::conv2d over the whole image) in the same run; one JSON line.",
            specs);
  if (!args.parse(argc, argv, 3)) return 0;
  const SensorConfig config = loadSensorFromArgs(args);
  sparse::configureThreads(static_cast<int>(args.getInt("aten-threads")),
                           static_cast<int>(args.getInt("blas-threads")));
  Model model = benchModel(args, config);
  model.net->eval();
  if (!mirrorAverageFromName(args.get("symmetry"))) model.meta.inference_symmetry = InferenceSymmetry::kNone;
  const auto count = static_cast<std::uint64_t>(args.getInt("count"));
  const auto dense_count = static_cast<std::uint64_t>(args.getInt("dense-count"));
  const auto distinct = args.has("images") ? static_cast<std::uint64_t>(args.getInt("images")) : count;
  const auto items = simulate(config, std::max<std::uint64_t>({distinct, dense_count, 1}),
                              static_cast<std::uint64_t>(args.getInt("seed")));
  torch::NoGradGuard no_grad;
  // What calibration_node does before its first image (~warm_up), then a few images.
  const auto warm_start = Clock::now();
  model.net->warmUp(static_cast<int>(std::max(1u, std::thread::hardware_concurrency())));
  const double warm_up_s = msSince(warm_start) / 1000.0;
  for (std::size_t i = 0; i < std::min<std::size_t>(5, items.size()); ++i) model.predict({items[i].image});

  double sites = 0;
  std::vector<double> cpu_ms;  // of the last timeSparse
  auto timeSparse = [&] {
    std::vector<double> ms;
    sites = 0;
    cpu_ms.clear();
    for (std::uint64_t i = 0; i < count; ++i) {
      const auto t0 = Clock::now();
      const double cpu0 = threadCpuMs();
      const auto p = model.predict({items[i % items.size()].image});
      cpu_ms.push_back(threadCpuMs() - cpu0);
      ms.push_back(msSince(t0));
      sites += p[0].active_sites;
    }
    return ms;
  };
  // What the estimator runs; where it skips the backbone (nothing it
  // publishes reads it), the whole network too, for the like-for-like
  // comparison with the dense run. The pattern head has no network to
  // compare (dense_images 0).
  const bool backbone_skipped = !model.net->backboneNeeded();
  const bool pattern = model.meta.arch.pattern_head;
  const std::uint64_t dense_runs = pattern ? 0 : dense_count;
  const std::vector<double> sparse_ms = timeSparse();
  const std::vector<double> sparse_cpu_ms = cpu_ms;
  std::vector<double> network_ms = sparse_ms;
  if (backbone_skipped && !pattern) {
    model.net->setSkipUnusedBackbone(false);
    network_ms = timeSparse();
    model.net->setSkipUnusedBackbone(true);
  }
  std::vector<double> dense_ms;
  const std::string sparse_threads = sparse::threadSummary();
  sparse::configureThreads(static_cast<int>(args.getInt("dense-aten-threads")), 1);
  Progress progress("dense network", dense_runs);
  for (std::uint64_t i = 0; i < dense_runs; ++i) {
    const auto t0 = Clock::now();
    const auto out = model.net->forwardDense(encodeImagesDense({items[i].image}, model.meta.input));
    (void)out.angles.sum().item<float>();
    dense_ms.push_back(msSince(t0));
    progress.update(i + 1);
  }
  progress.finish();
  const double sparse_median = percentile(sparse_ms, 0.5), network_median = percentile(network_ms, 0.5),
               dense_median = percentile(dense_ms, 0.5);
  std::cout << "{\"bench\":\"infer\",\"sensor\":\"" << config.name << "\",\"arch\":\"" << model.meta.arch.name
            << "\",\"parameters\":" << model.net->parameterCount() << ",\"inference_symmetry\":\""
            << inferenceSymmetryName(model.meta.inference_symmetry) << "\",\"sparse_threads\":\"" << sparse_threads
            << "\",\"dense_threads\":\"" << sparse::threadSummary() << "\",\"images\":" << count
            << ",\"mean_active_sites\":" << sites / std::max<std::uint64_t>(1, count)
            << ",\"backbone_skipped\":" << (backbone_skipped ? "true" : "false")
            << ",\"sparse_median_ms\":" << sparse_median << ",\"sparse_p99_ms\":" << percentile(sparse_ms, 0.99)
            << ",\"sparse_cpu_median_ms\":" << percentile(sparse_cpu_ms, 0.5)
            << ",\"sparse_network_median_ms\":" << network_median << ",\"dense_images\":" << dense_runs
            << ",\"dense_median_ms\":" << dense_median << ",\"dense_p99_ms\":" << percentile(dense_ms, 0.99)
            << ",\"dense_over_sparse\":" << (network_median > 0 && !pattern ? dense_median / network_median : 0.0)
            << ",\"warm_up_s\":" << warm_up_s << "}" << std::endl;
  return 0;
}

int runBenchTrain(int argc, char** argv) {
  auto specs = nnBenchOptions("2");  // measured: batch-64 GEMMs gain 1.45x from a second thread
  specs.insert(specs.end(), {
                                {"batch", "B", "images per step", "64", false, false},
                                {"steps", "N", "timed optimizer steps (after 2 warm-up steps)", "20", false, false},
                                {"images", "N", "distinct simulated images cycled through", "256", false, false},
                            });
  Args args("dss bench train",
            "SSCNN training throughput: forward + backward + AdamW step on the trainer's loss, sparse batches "
            "(rulebooks built per batch, as in training); one JSON line.",
            specs);
  if (!args.parse(argc, argv, 3)) return 0;
  const SensorConfig config = loadSensorFromArgs(args);
  sparse::configureThreads(static_cast<int>(args.getInt("aten-threads")),
                           static_cast<int>(args.getInt("blas-threads")));
  Model model = benchModel(args, config);
  model.net->train();
  const auto batch = static_cast<std::size_t>(args.getInt("batch"));
  const auto steps = static_cast<int>(args.getInt("steps"));
  const auto items = simulate(config, static_cast<std::uint64_t>(std::max<long long>(args.getInt("images"), 1)),
                              static_cast<std::uint64_t>(args.getInt("seed")));
  if (batch < 1 || steps < 1) throw UsageError("dss bench train: --batch and --steps must be positive");
  torch::optim::AdamW optimizer(model.net->parameters(), torch::optim::AdamWOptions(TrainOptions().learning_rate));
  std::size_t next = 0;
  double sites = 0, step_ms = 0;
  for (int step = -2; step < steps; ++step) {
    std::vector<cv::Mat> images;
    std::vector<float> targets;
    std::vector<std::int64_t> classes;
    for (std::size_t b = 0; b < batch; ++b, next = (next + 1) % items.size()) {
      images.push_back(items[next].image);
      targets.push_back(static_cast<float>(items[next].truth.alpha_rad / model.meta.angle_scale_rad));
      targets.push_back(static_cast<float>(items[next].truth.beta_rad / model.meta.angle_scale_rad));
      classes.push_back(std::max(0, items[next].truth.subfov_class));
    }
    const auto input = encodeImages(images, model.meta.input);  // the trainer keeps these in memory
    const auto target = torch::tensor(targets).view({-1, 2});
    const auto t0 = Clock::now();
    optimizer.zero_grad();
    const auto out = model.net->forward(input);
    const auto loss = trainingLoss(out, target, torch::tensor(classes), model.meta.arch.residual_scale,
                                   TrainOptions().class_loss_weight);
    loss.backward();
    optimizer.step();
    if (step >= 0) {
      step_ms += msSince(t0);
      sites += static_cast<double>(input.sites->size());
    }
  }
  std::cout << "{\"bench\":\"train\",\"sensor\":\"" << config.name << "\",\"arch\":\"" << model.meta.arch.name
            << "\",\"parameters\":" << model.net->parameterCount() << ",\"threads\":\"" << sparse::threadSummary()
            << "\",\"batch\":" << batch << ",\"steps\":" << steps << ",\"ms_per_step\":" << step_ms / steps
            << ",\"images_per_s\":" << 1000.0 * static_cast<double>(batch) * steps / step_ms
            << ",\"mean_active_sites\":" << sites / (static_cast<double>(batch) * steps) << "}" << std::endl;
  return 0;
}

}  // namespace dss::cli
