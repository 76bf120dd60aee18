// dss calibrate-sigma: on labelled held-out images, optionally sets the
// model's inference symmetry (model/symmetry) and refits its smooth angle
// correction (src/train/bias_calibration), then refits the level of its
// predicted uncertainty (src/train/sigma_calibration), records their input
// envelope (model/input_envelope) and, for a geometric head, its spot-mismatch
// level and optionally the unit tolerances' sigma (model/unit_calibration)
// and its spot bias (model/spot_bias), and writes the model.
#include <algorithm>
#include <cmath>
#include <iostream>
#include <optional>

#include "bag_reading.h"
#include "commands.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/model/input_envelope.h"
#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/model/spot_bias.h"
#include "digital_sun_sensor/model/unit_calibration.h"
#include "digital_sun_sensor/ros/dataset_source.h"
#include "digital_sun_sensor/sparse/threads.h"
#include "digital_sun_sensor/train/bias_calibration.h"
#include "digital_sun_sensor/train/sigma_calibration.h"
#include "progress.h"

namespace dss::cli {

int runCalibrateSigma(int argc, char** argv) {
  Args args(
      "dss calibrate-sigma",
      "Optionally refits a smooth correction of the model's angles (Legendre polynomials of the estimated angles, "
      "the degree chosen by two-fold cross-validation on these images), then scales its predicted sigma per axis so "
      "that 68.27 % of the errors on the given labelled images lie "
      "within 1 sigma (use images the model was not trained on; where the predicted sigma's shape is worse than none, "
      "a constant sigma per axis replaces it, scaled as a power of the image's lit-site count when that covers images "
      "of few and many lit sites alike), and records the range of lit pixels of those "
      "images as the model's input envelope (calibration_node flags images outside it out_of_distribution); "
      "writes the model atomically and prints one JSON line with the factors, the envelope and the 1/2/3-sigma "
      "coverage before and after.",
      {
          {"model", "MODEL", "model file to calibrate", "", true, false},
          {"data", "BAG", "labelled dataset bag(s) of the model's sensor", "", true, true},
          {"out", "MODEL", "model file to write (may be --model)", "", true, false},
          {"max-images", "N", "use at most N images, over all bags (0: all)", "5000", false, false},
          {"correction-degree", "D",
           "angle correction: 'keep' the model's, 'none', or refit one of degree at most D (0.." +
               std::to_string(AngleCorrection::kMaxDegree) + ")",
           "keep", false, false},
          {"symmetry", "S",
           "average the estimates over the sensor's mirror images: 'keep' the model's, 'none', 'flips' (4 images) or "
           "'dihedral' (8; square detectors); the sensor must have the symmetry",
           "keep", false, false},
          {"spot-bias-degree", "D",
           "geometric head: refit where the network reads each aperture class's whole spot off the ray trace "
           "(apertures of equal flux; a smooth function of the sun angles of degree at most D, 0.." +
               std::to_string(AngleCorrection::kMaxDegree) +
               ", chosen by two-fold cross-validation on these design images: each class's departure from the spots' "
               "mean, which the angle correction keeps) before the correction; 'keep' the model's, 'none' to drop it",
           "keep", false, false},
          {"unit-tolerances", "SCALE",
           "geometric head: add to every estimate's sigma the error the design's geometry makes on a unit built to "
           "SCALE x typical tolerances (1: 20 um height, 10 um offset, 0.2 deg rotation, 0.1 deg tilt, 1 um per "
           "aperture), for a family model used on units it was not calibrated on; 'keep' the model's geometry sigma",
           "keep", false, false},
          {"sigma", "MODE",
           "'refit' sigma's scale (or constant) on these images, or 'keep' the model's: with --spot-mismatch keep and "
           "the other steps kept, only the input envelope widens to these images (anomalous ones, say, whose errors "
           "and spots are not what sigma and the mismatch level should be fitted to)",
           "refit", false, false},
          {"spot-mismatch", "MODE",
           "geometric head: 'refit' the spot-mismatch level (what model_mismatch is judged against) on these images, "
           "or 'keep' the model's",
           "refit", false, false},
      });
  if (!args.parse(argc, argv, 2)) return 0;
  auto refitOrKeep = [&](const std::string& option) {
    if (args.get(option) != "refit" && args.get(option) != "keep")
      throw UsageError("dss calibrate-sigma: --" + option + " must be refit or keep, not " + args.get(option));
    return args.get(option) == "refit";
  };
  const bool refit_sigma = refitOrKeep("sigma"), refit_mismatch = refitOrKeep("spot-mismatch");
  // Checked before the bags are read, which can take minutes.
  const std::string correction = args.get("correction-degree");
  std::optional<int> max_degree;  // none: keep the model's correction
  if (correction != "keep") {
    max_degree = correction == "none" ? AngleCorrection::kNone : static_cast<int>(args.getInt("correction-degree"));
    if (*max_degree < AngleCorrection::kNone || *max_degree > AngleCorrection::kMaxDegree)
      throw UsageError("dss calibrate-sigma: --correction-degree must be keep, none or 0.." +
                       std::to_string(AngleCorrection::kMaxDegree) + ", not " + correction);
  }
  std::optional<int> spot_bias_degree;  // none: keep the model's spot bias
  if (args.get("spot-bias-degree") != "keep") {
    spot_bias_degree = args.get("spot-bias-degree") == "none" ? AngleCorrection::kNone
                                                              : static_cast<int>(args.getInt("spot-bias-degree"));
    if (*spot_bias_degree < AngleCorrection::kNone || *spot_bias_degree > AngleCorrection::kMaxDegree)
      throw UsageError("dss calibrate-sigma: --spot-bias-degree must be keep, none or 0.." +
                       std::to_string(AngleCorrection::kMaxDegree) + ", not " + args.get("spot-bias-degree"));
  }
  std::optional<InferenceSymmetry> symmetry;  // none: keep the model's
  if (args.get("symmetry") != "keep") {
    try {
      symmetry = parseInferenceSymmetry(args.get("symmetry"));
    } catch (const std::invalid_argument& e) {
      throw UsageError(std::string("dss calibrate-sigma: --symmetry: ") + e.what() + " (or 'keep')");
    }
  }
  std::optional<double> unit_tolerances;  // none: keep the model's geometry sigma
  if (args.get("unit-tolerances") != "keep") {
    unit_tolerances = args.getDouble("unit-tolerances");
    if (!(*unit_tolerances >= 0.0) || !std::isfinite(*unit_tolerances))
      throw UsageError("dss calibrate-sigma: --unit-tolerances must be 'keep' or a non-negative scale, not " +
                       args.get("unit-tolerances"));
  }
  sparse::configureThreads(1, 2);
  Model model = loadModel(args.get("model"));
  for (const char* option : {"unit-tolerances", "spot-bias-degree"})
    if (args.get(option) != "keep" && !model.meta.arch.geometric_head)
      throw UsageError(std::string("dss calibrate-sigma: --") + option + " needs a model with a geometric head (" +
                       args.get("model") + " has none)");
  const SensorConfig sensor = parseSensorConfig(model.meta.sensor_yaml, args.get("model") + " (sensor)");
  if (symmetry && *symmetry != InferenceSymmetry::kNone && model.meta.arch.geometric_head)
    throw UsageError("dss calibrate-sigma: --symmetry " + args.get("symmetry") +
                     ": the geometric head solves through the sensor's own geometry, which a mirror image does not "
                     "share once a unit is calibrated; use none");
  if (symmetry) {
    const std::string why = symmetryMismatch(sensor, *symmetry);
    if (!why.empty())
      throw UsageError("dss calibrate-sigma: --symmetry " + args.get("symmetry") + ": sensor '" + sensor.name +
                       "' lacks that symmetry: " + why);
    // Before the fits: the correction and the sigma are those of the averaged estimates.
    model.meta.inference_symmetry = *symmetry;
  }
  const auto max_images = static_cast<std::uint64_t>(args.getInt("max-images"));
  const TrainingData data = readLabelledBags("calibrate-sigma", args.all("data"), sensor, {}, max_images);
  // The envelope recorded in training (which may have included anomalies)
  // widened to these images: it covers all the model has been fitted to.
  const InputEnvelope envelope =
      covering(inputEnvelopeOf(model.meta), measureInputEnvelope(data.samples.siteCounts(model.meta.input.max_sites)));
  const std::size_t n = std::min<std::size_t>(max_images ? max_images : data.samples.size(), data.samples.size());
  // The model's predictions on the images, once per fit: minutes for a large model.
  std::optional<SpotBiasFit> spot_bias;
  if (spot_bias_degree) {
    if (!model.meta.spot_bias.by_height.empty())
      std::cerr << "calibrate-sigma: the spot bias's changes with the mask height were fitted against the bias "
                   "replaced here and are dropped: rerun dss calibrate-height\n";
    setSpotBias(model, SpotBias{});
    if (*spot_bias_degree != AngleCorrection::kNone) {
      std::cerr << "calibrate-sigma: spot bias on " << n << " images\n";
      spot_bias = fitSpotBias(model, readUnitImages(model, data.samples, n), *spot_bias_degree);
      setSpotBias(model, spot_bias->bias);
      std::cerr << "spot bias: degree " << spot_bias->bias.degree << " over " << spot_bias->bias.x_um.size()
                << " aperture classes, " << spot_bias->spots << " whole spots, RMS " << spot_bias->rms_before_um
                << " -> " << spot_bias->rms_after_um << " um\n";
    }
  }
  std::optional<BiasCalibration> bias;
  if (max_degree) {
    Progress bar("calibrate-sigma: correction", n);
    bias = calibrateBias(model, data.samples, n, *max_degree, false,
                         [&](std::size_t done, std::size_t) { bar.update(done); });
    bar.finish();
    std::cerr << "angle correction: degree " << bias->degree << " (cross-validated RMS "
              << bias->cross_validated_rms_deg[static_cast<std::size_t>(bias->degree + 1)] << " deg, none "
              << bias->cross_validated_rms_deg.front() << " deg; " << bias->outliers << " outliers left out)\n";
  }
  std::optional<SigmaCalibration> c;
  if (refit_sigma) {
    Progress sigma_bar("calibrate-sigma: sigma", n);
    c = calibrateSigma(model, data.samples, n, [&](std::size_t done, std::size_t) { sigma_bar.update(done); });
    sigma_bar.finish();
  }
  std::optional<MismatchCalibration> mismatch;
  if (model.meta.arch.geometric_head && refit_mismatch) {
    try {
      mismatch = calibrateSpotMismatch(model, data.samples, max_images);
    } catch (const std::invalid_argument& e) {
      std::cerr << "spot mismatch level not measured: " << e.what() << "\n";
    }
  }
  if (unit_tolerances) {
    // Propagated on the same images; the sigma scale above was fitted without it.
    model.meta.geometry_sigma_rad = unitToleranceSigma(model, data.samples, asBuiltTolerances(*unit_tolerances));
    std::cerr << "unit tolerances x" << *unit_tolerances << ": geometry sigma "
              << radToDeg(model.meta.geometry_sigma_rad[0]) << " / " << radToDeg(model.meta.geometry_sigma_rad[1])
              << " deg\n";
  }
  recordInputEnvelope(model.meta, envelope);
  saveModel(model, args.get("out"));
  std::cerr << "wrote " << args.get("out") << "\n";
  auto coverage = [](const char* name, const Coverage& cov) {
    std::ostringstream o;
    for (int k = 0; k < 3; ++k) o << ", \"" << name << "_within_" << k + 1 << "sigma\": " << cov.within[k];
    return o.str();
  };
  std::cout << "{\"command\": \"calibrate-sigma\", \"model\": \"" << args.get("out") << "\", \"samples\": " << n
            << ", \"lit_sites_min\": " << envelope.min_sites << ", \"lit_sites_max\": " << envelope.max_sites;
  if (c)
    std::cout << ", \"sigma_mode\": \"" << (c->constant ? (c->site_law.active() ? "lit_sites" : "constant") : "head")
              << "\", \"sigma_site_exponent\": " << c->site_law.exponent
              << ", \"sigma_site_reference\": " << c->site_law.reference_sites
              << ", \"constant_sigma_alpha_deg\": " << radToDeg(c->constant_sigma_alpha_rad)
              << ", \"constant_sigma_beta_deg\": " << radToDeg(c->constant_sigma_beta_rad);
  else
    std::cout << ", \"sigma_mode\": \"kept\"";
  if (model.meta.arch.geometric_head) std::cout << ", \"spot_bias_degree\": " << model.meta.spot_bias.degree;
  if (spot_bias) {
    std::cout << ", \"spot_bias_spots\": " << spot_bias->spots
              << ", \"spot_bias_rms_um_before\": " << spot_bias->rms_before_um
              << ", \"spot_bias_rms_um_after\": " << spot_bias->rms_after_um << ", \"spot_bias_cv_rms_um\": [";
    for (std::size_t k = 0; k < spot_bias->cross_validated_rms_um.size(); ++k)
      std::cout << (k ? ", " : "") << spot_bias->cross_validated_rms_um[k];
    std::cout << "]";
  }
  std::cout << ", \"correction_degree\": " << model.meta.angle_correction.degree << ", \"inference_symmetry\": \""
            << inferenceSymmetryName(model.meta.inference_symmetry) << "\"";
  if (bias) {
    std::cout << ", \"correction_cv_rms_deg\": [";
    for (std::size_t k = 0; k < bias->cross_validated_rms_deg.size(); ++k)
      std::cout << (k ? ", " : "") << bias->cross_validated_rms_deg[k];
    std::cout << "], \"correction_rms_alpha_before_deg\": " << bias->rms_alpha_before_deg
              << ", \"correction_rms_beta_before_deg\": " << bias->rms_beta_before_deg
              << ", \"correction_rms_alpha_after_deg\": " << bias->rms_alpha_after_deg
              << ", \"correction_rms_beta_after_deg\": " << bias->rms_beta_after_deg;
  }
  if (mismatch)
    std::cout << ", \"mismatch_level\": " << mismatch->level << ", \"mismatch_threshold\": " << mismatch->threshold
              << ", \"mismatch_flagged_fraction\": " << mismatch->flagged_fraction;
  std::cout << ", \"geometry_sigma_deg\": [" << radToDeg(model.meta.geometry_sigma_rad[0]) << ", "
            << radToDeg(model.meta.geometry_sigma_rad[1]) << "]";
  if (c)
    std::cout << ", \"scale_alpha\": " << c->scale_alpha << ", \"scale_beta\": " << c->scale_beta
              << coverage("before_alpha", c->alpha_before) << coverage("before_beta", c->beta_before)
              << coverage("after_alpha", c->alpha_after) << coverage("after_beta", c->beta_after);
  std::cout << "}" << std::endl;
  return 0;
}

}  // namespace dss::cli
