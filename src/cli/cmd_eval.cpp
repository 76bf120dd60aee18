#include <atomic>
#include <chrono>
#include <iostream>
#include <memory>
#include <thread>

#include "commands.h"
#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/estimate/estimator_factory.h"
#include "digital_sun_sensor/estimate/screened_estimator.h"
#include "digital_sun_sensor/eval/crlb.h"
#include "digital_sun_sensor/eval/evaluation.h"
#include "digital_sun_sensor/ros/dataset_source.h"
#include "digital_sun_sensor/sparse/threads.h"
#include "progress.h"

namespace dss::cli {
namespace {

// Bounds on up to `max_samples` evenly spaced images, those of them with a
// valid estimate, on `threads` threads. The spacing runs over every image,
// not over the valid ones, so that two estimators evaluated on the same bag
// are held to bounds on the same images (less the ones each declines).
void computeBounds(std::vector<EvalRecord>& records, const CrlbCalculator& crlb, std::size_t max_samples, int threads) {
  if (max_samples == 0 || records.empty()) return;
  const std::size_t stride = std::max<std::size_t>(1, (records.size() + max_samples - 1) / max_samples);
  std::vector<std::size_t> picked;
  for (std::size_t i = 0; i < records.size(); i += stride)
    if (records[i].estimate.valid) picked.push_back(i);
  Progress progress("eval: crlb", picked.size());
  std::atomic<std::size_t> next{0}, done{0};
  // Takes the next record; false when none is left.
  auto computeNext = [&] {
    const std::size_t k = next++;
    if (k >= picked.size()) return false;
    EvalRecord& r = records[picked[k]];
    const Eigen::Matrix2d cov = crlb.covariance(r.alpha_true_rad, r.beta_true_rad);
    r.crlb_alpha_rad2 = cov(0, 0);
    r.crlb_beta_rad2 = cov(1, 1);
    const Eigen::Matrix2d readout = crlb.readoutCovariance(r.alpha_true_rad, r.beta_true_rad);
    r.readout_crlb_alpha_rad2 = readout(0, 0);
    r.readout_crlb_beta_rad2 = readout(1, 1);
    ++done;
    return true;
  };
  std::vector<std::thread> pool;
  for (int t = 1; t < threads; ++t)
    pool.emplace_back([&] {
      while (computeNext()) {
      }
    });
  // The calling thread works too and reports progress between items.
  while (computeNext()) progress.update(done);
  for (auto& t : pool) t.join();
  progress.finish();
}

constexpr std::uint64_t kCoarseSeed = 0xC0A55E;

}  // namespace

int runEval(int argc, char** argv) {
  const std::string threads = std::to_string(std::max(1u, std::thread::hardware_concurrency()));
  Args args("dss eval",
            "Evaluates an estimator on a labelled dataset bag; prints one JSON line (keys: docs/design.md, Evaluation "
            "keys).\n"
            "Errors are |estimate - truth| over the images the estimator marked valid.",
            {
                {"data", "BAG", "dataset bag(s) of /sun_sensor/image + /sun_sensor/truth", "", true, true},
                {"estimator", "KIND:FILE", "sscnn:MODEL, centroid:CALIB or pattern:SENSOR_CONFIG", "", true, false},
                {"symmetry", "S",
                 "SSCNN: 'model' (average over the mirror images its file names) or 'none' (the image alone; "
                 "calibration_node's ~inference_symmetry)",
                 "model", false, false},
                {"csv", "FILE", "also write one CSV row per image", "", false, false},
                {"screen", "",
                 "apply calibration_node's screens (hot-pixel removal, saturation, predicted sigma, field "
                 "of view; default thresholds)",
                 "", false, false},
                {"spike-sigmas", "S",
                 "with --screen: its hot-pixel repair threshold (0: off; the baseline's own repair is its "
                 "calibration file's extraction.spike_sigmas)",
                 defaultText(kDefaultSpikeSigmas), false, false},
                {"subfov-hint", "",
                 "give the estimator each image's true sub-FOV class (as the published protocol gives its network; "
                 "a coarse sun sensor's quadrant): the pattern estimator, on a mask whose pattern repeats within "
                 "the field",
                 "", false, false},
                {"coarse-sigma-deg", "D",
                 "give the estimator a coarse sun direction per image, as a coarse sun sensor of this 1-sigma error "
                 "per axis would (the truth plus seeded normal noise; calibration_node's ~coarse_sun): chooses where "
                 "a repeating pattern fits two places (0: none)",
                 "0", false, false},
                {"crlb-samples", "N", "Cramer-Rao bound on N evenly spaced images, those answered (0: skip)", "200",
                 false, false},
                {"crlb-sensor", "design|unit",
                 "the sensor the bound is of: the design, or the one unit a bag of a built unit was drawn as "
                 "(dss generate --anomalies as_built=K; its mask pose and apertures)",
                 "design", false, false},
                {"batch", "B", "images per estimator call", "16", false, false},
                {"max-images", "N", "evaluate at most N images (0: all)", "0", false, false},
                {"threads", "T", "threads for the bound", threads, false, false},
            });
  if (!args.parse(argc, argv, 2)) return 0;
  ScreenOptions screen;
  screen.spike_sigmas = args.getDouble("spike-sigmas");
  try {
    screen.validate();
  } catch (const std::invalid_argument& e) {
    throw UsageError(std::string("dss eval: --spike-sigmas: ") + e.what());
  }
  EstimatorOptions estimator_options;
  try {
    estimator_options.mirror_average = mirrorAverageFromName(args.get("symmetry"));
  } catch (const std::invalid_argument& e) {
    throw UsageError(std::string("dss eval: --symmetry: ") + e.what());
  }
  const std::string crlb_sensor = args.get("crlb-sensor");
  if (crlb_sensor != "design" && crlb_sensor != "unit")
    throw UsageError("dss eval: --crlb-sensor must be design or unit (got '" + crlb_sensor + "')");
  sparse::configureThreads(1, 1);  // per-image inference is fastest single-threaded (README)
  const DatasetBagReader reader(args.all("data"));
  const std::size_t crlb_samples = static_cast<std::size_t>(args.getInt("crlb-samples"));
  // Drawn before the images are read, so that a bag of several sensors is refused at once.
  std::optional<SensorInstance> crlb_unit;
  if (crlb_sensor == "unit" && crlb_samples > 0) crlb_unit = drawnSensorFromBagInfo(reader);
  std::unique_ptr<SunEstimator> estimator;
  try {
    estimator = makeEstimator(args.get("estimator"), nullptr, estimator_options);
  } catch (const std::invalid_argument& e) {
    throw UsageError(std::string("dss eval: --estimator: ") + e.what());
  }
  if (args.has("screen")) estimator = std::make_unique<ScreenedEstimator>(std::move(estimator), screen);
  const SensorConfig& sensor = estimator->sensor();
  const auto batch_size = static_cast<std::size_t>(std::max(1LL, args.getInt("batch")));
  const auto max_images = static_cast<std::uint64_t>(args.getInt("max-images"));

  std::vector<EvalRecord> records;
  std::vector<cv::Mat> batch;
  std::vector<int> hints;
  const bool hinted = args.has("subfov-hint");
  const double coarse_sigma_rad = degToRad(args.getDouble("coarse-sigma-deg"));
  if (!(coarse_sigma_rad >= 0.0)) throw UsageError("dss eval: --coarse-sigma-deg must be >= 0");
  if (hinted && coarse_sigma_rad > 0.0)
    throw UsageError("dss eval: --subfov-hint and --coarse-sigma-deg exclude each other");
  CoarseDirections coarse;
  double estimator_ms = 0.0;
  auto flush = [&] {
    if (batch.empty()) return;
    const auto t0 = std::chrono::steady_clock::now();
    const std::vector<SunEstimate> estimates = hinted ? estimator->estimateWithSubFovHints(batch, hints)
                                               : coarse_sigma_rad > 0.0
                                                   ? estimator->estimateWithCoarseDirections(batch, coarse)
                                                   : estimator->estimate(batch);
    hints.clear();
    coarse.clear();
    estimator_ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    for (std::size_t k = 0; k < estimates.size(); ++k)
      records[records.size() - batch.size() + k].estimate = estimates[k];
    batch.clear();
  };
  Progress progress("eval: " + estimator->source(),
                    max_images ? std::min(max_images, reader.imageMessages()) : reader.imageMessages());
  const BagReadStats stats = reader.forEach([&](const LabelledImage& item) {
    checkImageFitsSensor(item, sensor);
    EvalRecord r;
    r.index = item.index;
    r.stamp_s = item.stamp.toSec();
    r.alpha_true_rad = item.truth.alpha;
    r.beta_true_rad = item.truth.beta;
    r.subfov_true = item.truth.subfov_class;
    records.push_back(r);
    batch.push_back(item.image);
    hints.push_back(item.truth.subfov_class);
    if (coarse_sigma_rad > 0.0) {
      Rng rng(deriveSeed(kCoarseSeed, item.index));  // the same reading of an image in every run
      coarse.push_back(CoarseDirection{item.truth.alpha + coarse_sigma_rad * rng.normal(),
                                       item.truth.beta + coarse_sigma_rad * rng.normal(), coarse_sigma_rad});
    }
    if (batch.size() >= batch_size) flush();
    progress.update(item.index + 1);
    return max_images == 0 || item.index + 1 < max_images;
  });
  flush();
  progress.finish();
  std::cerr << "read " << describe(stats) << "\n";
  if (records.empty()) throw std::runtime_error("no image/truth pairs in the data");

  // The bound needs the sensor that rendered the data: the bag's own config when it has one.
  if (crlb_samples > 0) {
    const std::optional<SensorConfig> rendered = sensorFromBagInfo(reader);
    const CrlbCalculator crlb = crlb_unit ? CrlbCalculator(*crlb_unit) : CrlbCalculator(rendered ? *rendered : sensor);
    computeBounds(records, crlb, crlb_samples, static_cast<int>(args.getInt("threads")));
  }

  const EvalSummary summary = summarize(records, estimator->source(), estimator_ms);
  if (args.has("csv")) {
    writeEvalCsv(args.get("csv"), records);
    std::cerr << "wrote " << records.size() << " rows to " << args.get("csv") << "\n";
  }
  std::cout << summary.toJson() << std::endl;
  return 0;
}

}  // namespace dss::cli
