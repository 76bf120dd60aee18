// dss recalibrate: replays images with reference sun directions (a recorded
// bag) through calibration_node's in-flight recalibration in stream order,
// as the node runs it: each batch estimated with the geometry in use, its
// pairs offered to the refit (model/unit_recalibration) and to the
// reference consistency (estimate/reference_consistency), which widens the
// sigma of estimates that disagree with the references; writes the
// recalibrated unit model. The offline twin of ~recalibration, for recorded
// flight data and for measuring it.
#include <yaml-cpp/yaml.h>

#include <cmath>
#include <iomanip>
#include <iostream>
#include <sstream>

#include "commands.h"
#include "digital_sun_sensor/common/estimate_status.h"
#include "digital_sun_sensor/common/file_io.h"
#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/estimate/reference_consistency.h"
#include "digital_sun_sensor/model/sscnn_estimator.h"
#include "digital_sun_sensor/model/unit_recalibration.h"
#include "digital_sun_sensor/ros/dataset_source.h"
#include "digital_sun_sensor/sparse/threads.h"
#include "progress.h"

namespace dss::cli {
namespace {

// One replayed image: truth, the reference the node was given, the estimate
// as published (sigma widened) and its own sigma.
struct ReplayRow {
  std::uint64_t index = 0;
  std::array<double, 2> truth_rad{}, reference_rad{}, own_sigma_rad{};
  SunEstimate published;
  bool widened = false;
  std::size_t refits = 0;
};

bool within(const ReplayRow& r, double sigmas, bool widened) {
  const double e[2] = {r.published.alpha_rad - r.truth_rad[0], r.published.beta_rad - r.truth_rad[1]};
  for (int axis = 0; axis < 2; ++axis) {
    const double sigma = widened ? std::sqrt(r.published.covariance[axis == 0 ? 0 : 3])
                                 : r.own_sigma_rad[static_cast<std::size_t>(axis)];
    if (!(std::abs(e[axis]) <= sigmas * sigma)) return false;
  }
  return true;
}

void writeReplayCsv(const std::string& path, const std::vector<ReplayRow>& rows) {
  std::ostringstream out;
  out << std::setprecision(10);
  out << "index,alpha_true_deg,beta_true_deg,alpha_reference_deg,beta_reference_deg,alpha_est_deg,beta_est_deg,"
         "alpha_sigma_deg,beta_sigma_deg,alpha_sigma_widened_deg,beta_sigma_widened_deg,widened,valid,status,refits\n";
  for (const ReplayRow& r : rows) {
    const SunEstimate& e = r.published;
    out << r.index << ',' << radToDeg(r.truth_rad[0]) << ',' << radToDeg(r.truth_rad[1]) << ','
        << radToDeg(r.reference_rad[0]) << ',' << radToDeg(r.reference_rad[1]) << ',' << radToDeg(e.alpha_rad) << ','
        << radToDeg(e.beta_rad) << ',' << radToDeg(r.own_sigma_rad[0]) << ',' << radToDeg(r.own_sigma_rad[1]) << ','
        << radToDeg(std::sqrt(e.covariance[0])) << ',' << radToDeg(std::sqrt(e.covariance[3])) << ',' << r.widened
        << ',' << e.valid << ',' << status::statusCode(e.status) << ',' << r.refits << '\n';
  }
  writeFileAtomic(path, out.str());
}

}  // namespace

int runRecalibrate(int argc, char** argv) {
  const RecalibrationOptions defaults;
  const ConsistencyOptions consistency_defaults;
  Args args(
      "dss recalibrate",
      "Replays a bag of images with reference sun directions (the truth topic: SunAngles, or a "
      "geometry_msgs/Vector3Stamped in the sensor frame) through the in-flight recalibration of calibration_node, "
      "in stream order and as the node runs it: each batch is estimated with the geometry in use; pairs whose "
      "reference is far from the estimate are refused by the refit, which refits the geometry of the model's "
      "geometric head from a bounded window once the references spread over the field, every --refit-every pairs; "
      "where the estimates disagree with the references beyond their sigma (a unit that drifted as a whole), their "
      "sigma is widened by the residual until a refit. Writes the recalibrated unit model atomically and prints one "
      "JSON line (the errors against the bag's truth, before any --reference-outliers).",
      {
          {"model", "MODEL", "geometric-head model of the unit (usually a unit model)", "", true, false},
          {"data", "BAG", "bag(s) of the unit's images with references", "", true, true},
          {"out", "MODEL", "unit model to write (may be --model)", "", true, false},
          {"max-images", "N", "replay at most the first N images (0: all)", "0", false, false},
          {"batch", "B", "images per estimator call (calibration_node's ~max_batch)", "4", false, false},
          {"window", "N", "pairs kept", std::to_string(defaults.window), false, false},
          {"min-pairs", "N", "pairs before the first refit", std::to_string(defaults.min_pairs), false, false},
          {"refit-every", "N", "new pairs between refits", std::to_string(defaults.refit_every), false, false},
          {"min-spread-deg", "D", "spread of the references (std of alpha and of beta) before any refit",
           std::to_string(defaults.min_spread_deg), false, false},
          {"max-disagreement-deg", "D", "references farther than this from the estimate are refused by the refit",
           std::to_string(defaults.max_disagreement_deg), false, false},
          {"reference-sigma-deg", "D", "the references' own error per axis (consistency)",
           std::to_string(consistency_defaults.reference_sigma_deg), false, false},
          {"consistency-window", "N", "recent pairs the consistency judges",
           std::to_string(consistency_defaults.window), false, false},
          {"consistency-min-pairs", "N", "pairs before the consistency judges",
           std::to_string(consistency_defaults.min_pairs), false, false},
          {"consistency-max-normalized", "Z",
           "robust RMS of residual / sigma beyond which sigma is widened (0: never widen)",
           std::to_string(consistency_defaults.max_normalized), false, false},
          {"reference-outliers", "F",
           "robustness test: replace this fraction of the references by directions 2 to 5 deg off (seeded)", "0", false,
           false},
          {"seed", "S", "seed of --reference-outliers", "1", false, false},
          {"csv", "FILE", "also write one CSV row per image (truth, reference, estimate, own and widened sigma)", "",
           false, false},
          {"image-topic", "TOPIC", "image topic in the bags", DatasetTopics{}.image, false, false},
          {"truth-topic", "TOPIC", "reference topic in the bags", DatasetTopics{}.truth, false, false},
      });
  if (!args.parse(argc, argv, 2)) return 0;
  RecalibrationOptions options;
  auto count = [&](const char* name) {
    const long long v = args.getInt(name);
    if (v < 1) throw UsageError(std::string("dss recalibrate: --") + name + " must be at least 1");
    return static_cast<std::size_t>(v);
  };
  options.window = count("window");
  options.min_pairs = count("min-pairs");
  options.refit_every = count("refit-every");
  options.min_spread_deg = args.getDouble("min-spread-deg");
  options.max_disagreement_deg = args.getDouble("max-disagreement-deg");
  ConsistencyOptions consistency_options;
  consistency_options.window = count("consistency-window");
  consistency_options.min_pairs = count("consistency-min-pairs");
  consistency_options.reference_sigma_deg = args.getDouble("reference-sigma-deg");
  const double max_normalized = args.getDouble("consistency-max-normalized");
  const bool widen = max_normalized != 0.0;
  if (widen) consistency_options.max_normalized = max_normalized;
  try {
    options.validate();
    consistency_options.validate();
  } catch (const std::invalid_argument& e) {
    throw UsageError(std::string("dss recalibrate: ") + e.what());
  }
  const double outlier_fraction = args.getDouble("reference-outliers");
  if (!(outlier_fraction >= 0.0 && outlier_fraction <= 1.0))
    throw UsageError("dss recalibrate: --reference-outliers must lie in [0, 1]");
  const long long max_images = args.getInt("max-images");
  if (max_images < 0) throw UsageError("dss recalibrate: --max-images must be >= 0");
  const std::size_t batch_size = count("batch");
  sparse::configureThreads(1, 1);  // per-image inference is fastest single-threaded
  SscnnEstimator estimator(args.get("model"));
  if (!estimator.hasGeometry())
    throw UsageError("dss recalibrate: " + args.get("model") + " has no geometric head, so no geometry to refit");
  DatasetTopics topics;
  topics.image = args.get("image-topic");
  topics.truth = args.get("truth-topic");
  const DatasetBagReader reader(args.all("data"), topics);

  const MaskGeometry before = estimator.geometry();
  UnitRecalibrator recalibrator(options);
  ReferenceConsistency consistency(consistency_options);
  Rng rng(static_cast<std::uint64_t>(args.getInt("seed")));
  std::size_t corrupted = 0, failures = 0;
  std::vector<ReplayRow> rows;
  std::vector<cv::Mat> batch;
  auto flush = [&] {
    if (batch.empty()) return;
    const std::size_t first = rows.size() - batch.size();
    const std::vector<SunEstimate> estimates = estimator.estimate(batch);
    // As calibration_node pairs them: valid estimates and those the unit's
    // drift makes inconsistent (model_mismatch).
    std::vector<cv::Mat> paired;
    std::vector<std::array<double, 2>> references;
    std::vector<const SunEstimate*> estimated;
    for (std::size_t k = 0; k < batch.size(); ++k) {
      ReplayRow& row = rows[first + k];
      row.published = estimates[k];
      row.own_sigma_rad = {std::sqrt(estimates[k].covariance[0]), std::sqrt(estimates[k].covariance[3])};
      if (!estimates[k].valid && status::statusCode(estimates[k].status) != status::kModelMismatch) continue;
      paired.push_back(batch[k]);
      references.push_back(row.reference_rad);
      estimated.push_back(&estimates[k]);
    }
    for (std::size_t k = 0; k < estimated.size(); ++k) consistency.add(*estimated[k], references[k]);
    for (std::size_t k = 0; k < batch.size(); ++k) {
      ReplayRow& row = rows[first + k];
      if (widen) consistency.widen(row.published);
      row.widened = row.published.valid && consistency.inconsistent() && widen;
      row.refits = recalibrator.refits();
    }
    batch.clear();
    if (paired.empty()) return;
    // Due is judged pair by pair, as in the node.
    const std::vector<UnitImage> reads = estimator.readUnit(paired, references);
    for (std::size_t k = 0; k < reads.size() && k < estimated.size(); ++k) {
      recalibrator.add(reads[k], estimated[k]->alpha_rad, estimated[k]->beta_rad);
      if (!recalibrator.due()) continue;
      try {
        estimator.recalibrate(recalibrator);
        consistency.reset();
      } catch (const std::invalid_argument& e) {
        if (failures++ == 0) std::cerr << "refit failed: " << e.what() << "\n";
      }
    }
  };
  Progress progress("recalibrate",
                    max_images ? std::min<std::uint64_t>(static_cast<std::uint64_t>(max_images), reader.imageMessages())
                               : reader.imageMessages());
  const BagReadStats stats = reader.forEach([&](const LabelledImage& item) {
    checkImageFitsSensor(item, estimator.sensor());
    ReplayRow row;
    row.index = item.index;
    row.truth_rad = {item.truth.alpha, item.truth.beta};
    row.reference_rad = row.truth_rad;
    if (rng.uniform() < outlier_fraction) {
      const double size = degToRad(rng.uniform(2.0, 5.0)), direction = rng.uniform(0.0, 2.0 * M_PI);
      row.reference_rad[0] += size * std::cos(direction);
      row.reference_rad[1] += size * std::sin(direction);
      ++corrupted;
    }
    rows.push_back(row);
    batch.push_back(item.image);
    if (batch.size() >= batch_size) flush();
    progress.update(item.index + 1);
    return max_images == 0 || item.index + 1 < static_cast<std::uint64_t>(max_images);
  });
  flush();
  progress.finish();
  std::cerr << "read " << describe(stats) << "\n";
  if (rows.empty()) throw std::runtime_error("no image/reference pairs in the data");
  if (args.has("csv")) writeReplayCsv(args.get("csv"), rows);
  if (!recalibrator.last())
    throw std::runtime_error("no refit: " + std::to_string(recalibrator.pairs()) + " pairs, spread " +
                             std::to_string(recalibrator.spreadDeg()) + " deg (needs " +
                             std::to_string(options.min_pairs) + " and " + std::to_string(options.min_spread_deg) +
                             " deg)");
  const UnitCalibrationReport& last = *recalibrator.last();
  YAML::Node record = YAML::Load(last.toYaml());
  record["data"] = "in flight (replayed): " + std::to_string(rows.size()) + " reference pairs of " +
                   args.all("data").front() + ", " + std::to_string(recalibrator.refits()) + " refits";
  estimator.saveModel(args.get("out"), YAML::Dump(record));
  std::cerr << "wrote " << args.get("out") << "\n";
  const MaskGeometry after = estimator.geometry();
  // Sigma coverage of the published estimates before the first refit (the
  // drifted geometry's), with their own sigma and as widened.
  std::size_t early = 0, own3 = 0, widened3 = 0, widened = 0;
  for (const ReplayRow& r : rows) {
    if (!r.published.valid) continue;
    widened += r.widened;
    if (r.refits > 0) continue;
    ++early;
    own3 += within(r, 3.0, false);
    widened3 += within(r, 3.0, true);
  }
  const auto share = [](std::size_t n, std::size_t of) { return of ? static_cast<double>(n) / of : 0.0; };
  std::cout << "{\"command\": \"recalibrate\", \"model\": \"" << args.get("out") << "\", \"pairs\": " << rows.size()
            << ", \"corrupted_references\": " << corrupted << ", \"refused\": " << recalibrator.refused()
            << ", \"refits\": " << recalibrator.refits() << ", \"failed_refits\": " << failures
            << ", \"window_pairs\": " << recalibrator.pairs() << ", \"spread_deg\": " << recalibrator.spreadDeg()
            << ", \"spots\": " << last.spots << ", \"outlier_spots\": " << last.outliers
            << ", \"spot_rms_um_before\": " << last.spot_rms_um_before
            << ", \"spot_rms_um_after\": " << last.spot_rms_um_after
            << ", \"height_change_um\": " << after.height_um - before.height_um << ", \"offset_change_um\": ["
            << after.offset_x_um - before.offset_x_um << ", " << after.offset_y_um - before.offset_y_um
            << "], \"height_sigma_um\": " << last.standard_errors[0] << ", \"widened_estimates\": " << widened
            << ", \"valid_before_first_refit\": " << early
            << ", \"within_3sigma_before_first_refit\": " << share(own3, early)
            << ", \"within_3sigma_widened_before_first_refit\": " << share(widened3, early) << "}" << std::endl;
  return 0;
}

}  // namespace dss::cli
