#include "digital_sun_sensor/eval/report.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <sstream>
#include <stdexcept>

#include "digital_sun_sensor/common/file_io.h"
#include "digital_sun_sensor/common/json.h"
#include "digital_sun_sensor/common/statistics.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/eval/evaluation.h"
#include "digital_sun_sensor/eval/plot.h"
#include "digital_sun_sensor/sim/dataset_generator.h"

namespace dss {
namespace {

using Progress = std::function<void(const std::string&, std::size_t, std::size_t)>;

struct Labelled {
  std::vector<cv::Mat> images;
  std::vector<ImageTruth> truths;
};

Labelled render(const SensorConfig& config, int count, std::uint64_t seed, int sensors, int threads,
                SamplingMode sampling = SamplingMode::kRandom, std::uint64_t offset = 0) {
  DatasetSpec spec;
  spec.count = static_cast<std::uint64_t>(count);
  spec.seed = seed;
  spec.instances = sensors;
  spec.threads = threads;
  spec.sampling = sampling;
  spec.offset = offset;
  Labelled out;
  DatasetGenerator(config, spec).run([&](const DatasetItem& item) {
    out.images.push_back(item.image);
    out.truths.push_back(item.truth);
  });
  return out;
}

std::vector<EvalRecord> evaluate(SunEstimator& estimator, const Labelled& data) {
  std::vector<EvalRecord> records(data.images.size());
  for (std::size_t first = 0; first < data.images.size(); first += 32) {
    const std::size_t last = std::min(data.images.size(), first + 32);
    const std::vector<cv::Mat> batch(data.images.begin() + first, data.images.begin() + last);
    const std::vector<SunEstimate> estimates = estimator.estimate(batch);
    for (std::size_t k = first; k < last; ++k) {
      EvalRecord& r = records[k];
      r.index = k;
      r.alpha_true_rad = data.truths[k].alpha_rad;
      r.beta_true_rad = data.truths[k].beta_rad;
      r.subfov_true = data.truths[k].subfov_class;
      r.estimate = estimates[k - first];
    }
  }
  return records;
}

// Mean |error| (deg) per cell of the FOV for one axis; NaN where no valid estimate.
cv::Mat errorMap(const std::vector<EvalRecord>& records, const SensorConfig& s, int bins, bool alpha) {
  cv::Mat sum(bins, bins, CV_64F, cv::Scalar(0)), count(bins, bins, CV_64F, cv::Scalar(0));
  const double a_max = s.fov.alpha_max_deg, b_max = s.fov.beta_max_deg;
  for (const auto& r : records) {
    if (!r.estimate.valid) continue;
    const int c =
        std::clamp(static_cast<int>((r.alpha_true_rad * kDegPerRad + a_max) / (2 * a_max) * bins), 0, bins - 1);
    const int w =
        std::clamp(static_cast<int>((r.beta_true_rad * kDegPerRad + b_max) / (2 * b_max) * bins), 0, bins - 1);
    const double e = alpha ? r.estimate.alpha_rad - r.alpha_true_rad : r.estimate.beta_rad - r.beta_true_rad;
    sum.at<double>(w, c) += std::abs(e) * kDegPerRad;
    count.at<double>(w, c) += 1.0;
  }
  cv::Mat mean(bins, bins, CV_64F);
  for (int i = 0; i < bins * bins; ++i)
    mean.at<double>(i) = count.at<double>(i) > 0 ? sum.at<double>(i) / count.at<double>(i) : std::nan("");
  return mean;
}

std::vector<double> signedErrorsDeg(const std::vector<EvalRecord>& records, bool alpha) {
  std::vector<double> e;
  for (const auto& r : records)
    if (r.estimate.valid)
      e.push_back((alpha ? r.estimate.alpha_rad - r.alpha_true_rad : r.estimate.beta_rad - r.beta_true_rad) *
                  kDegPerRad);
  return e;
}

// Observed fraction of |error| <= k sigma for k on `ks`.
std::vector<double> reliability(const std::vector<EvalRecord>& records, bool alpha, const std::vector<double>& ks) {
  std::vector<double> z;
  for (const auto& r : records) {
    if (!r.estimate.valid) continue;
    const double e = alpha ? r.estimate.alpha_rad - r.alpha_true_rad : r.estimate.beta_rad - r.beta_true_rad;
    const double var = r.estimate.covariance[alpha ? 0 : 3];
    z.push_back(var > 0 ? std::abs(e) / std::sqrt(var) : INFINITY);
  }
  std::vector<double> out;
  for (double k : ks)
    out.push_back(z.empty() ? NAN : std::count_if(z.begin(), z.end(), [k](double v) {
                                      return v <= k;
                                    }) / static_cast<double>(z.size()));
  return out;
}

// One noise or anomaly term swept from none to severe.
struct Term {
  std::string name, label, unit;
  std::vector<double> levels;
  std::function<void(SensorConfig&, double)> apply;
};

std::vector<Term> terms() {
  return {
      {"shot_noise", "shot noise", "off / on", {0, 1}, [](SensorConfig& c, double v) { c.noise.shot_noise = v > 0; }},
      {"read_noise", "read noise", "e-", {0, 3, 10, 30}, [](SensorConfig& c, double v) { c.noise.read_noise_e = v; }},
      {"dark_current",
       "dark current (temperature)",
       "deg C",
       {25, 45, 65, 85},
       [](SensorConfig& c, double v) { c.noise.temperature_c = v; }},
      {"prnu", "PRNU", "fraction", {0, 0.01, 0.05, 0.2}, [](SensorConfig& c, double v) { c.noise.prnu_fraction = v; }},
      {"dsnu", "DSNU", "fraction", {0, 0.3, 1, 3}, [](SensorConfig& c, double v) { c.noise.dsnu_fraction = v; }},
      {"hot_pixels",
       "hot pixels",
       "count",
       {0, 30, 300, 3000},
       [](SensorConfig& c, double v) { c.anomalies.hot_pixel_count = static_cast<int>(v); }},
      {"stray_light",
       "stray light / albedo",
       "fraction of full well",
       {0, 0.1, 0.3, 0.6},
       [](SensorConfig& c, double v) {
         c.anomalies.stray_light_probability = v > 0 ? 1.0 : 0.0;
         c.anomalies.stray_light_max_fraction = v;
       }},
      {"ghost",
       "ghost reflection",
       "reflectance",
       {0, 0.02, 0.05, 0.1},
       [](SensorConfig& c, double v) {
         c.anomalies.ghost_probability = v > 0 ? 1.0 : 0.0;
         c.anomalies.ghost_reflectance = v;
       }},
      {"debris",
       "debris on an aperture",
       "max blocked fraction",
       {0, 0.1, 0.3, 0.6},
       [](SensorConfig& c, double v) {
         // One aperture per drawn sensor on average (a particle, not a film
         // over the whole mask); each occluded aperture's diffraction is
         // computed anew, so this also bounds the sweep's cost on large masks.
         const double apertures = static_cast<double>(std::max<std::size_t>(1, c.mask.apertures.size()));
         c.anomalies.debris_probability = v > 0 ? 1.0 / apertures : 0.0;
         c.anomalies.debris_max_blocked_fraction = v;
       }},
      {"as_built",
       "as-built errors (mount, aperture positions)",
       "x typical tolerances",
       {0, 0.3, 1, 3},
       [](SensorConfig& c, double v) {
         c.as_built = asBuiltTolerances(v);
         // Diameter errors give every aperture of every drawn sensor its own
         // diffraction pattern to compute, minutes on 49 apertures: left to
         // the anomaly tables (dss generate --anomalies as_built=S).
         c.as_built.aperture_diameter_sigma_um = 0.0;
       }},
  };
}

struct SweepResult {
  std::vector<double> mean_deg[2], valid[2];  // [estimator][level]
};

std::string jsonArray(const std::vector<double>& v) {
  std::string s = "[";
  for (std::size_t i = 0; i < v.size(); ++i) s += (i ? ", " : "") + json::number(v[i]);
  return s + "]";
}

std::string html(const std::string& s) {
  std::string out;
  for (char c : s) out += c == '<' ? "&lt;" : c == '>' ? "&gt;" : c == '&' ? "&amp;" : std::string(1, c);
  return out;
}

std::string fixed(double v, int digits) {
  if (!std::isfinite(v)) return "&mdash;";
  std::ostringstream o;
  o.setf(std::ios::fixed);
  o.precision(digits);
  o << v;
  return o.str();
}

}  // namespace

void ReportOptions::validate() const {
  if (out_dir.empty()) throw std::invalid_argument("report: no output directory");
  if (test_images < 20) throw std::invalid_argument("report: test_images must be >= 20");
  if (sweep_images < 1) throw std::invalid_argument("report: sweep_images must be >= 1");
  if (sweep_sensors < 1) throw std::invalid_argument("report: sweep_sensors must be >= 1");
  if (map_bins < 2) throw std::invalid_argument("report: map_bins must be >= 2");
  if (threads < 1) throw std::invalid_argument("report: threads must be >= 1");
  if (published_images < 20) throw std::invalid_argument("report: published_images must be >= 20");
}

std::string writeReport(const SensorConfig& sensor, SunEstimator& sscnn, SunEstimator* baseline, const ReportOptions& o,
                        const Progress& progress, const PublishedProtocolRun* published) {
  o.validate();
  // Built in "<out>.partial" and moved into place when complete: a killed run
  // never leaves a report whose pages and figures disagree.
  std::filesystem::path out = std::filesystem::path(o.out_dir).lexically_normal();
  if (!out.has_filename()) out = out.parent_path();  // "out/" -> "out"
  const std::string staged = out.string() + ".partial";
  std::filesystem::remove_all(staged);
  std::filesystem::create_directories(staged);
  const std::string dir = staged + "/";
  auto report = [&](const std::string& stage, std::size_t done, std::size_t total) {
    if (progress) progress(stage, done, total);
  };
  const std::vector<std::string> names = {"SSCNN", "baseline"};
  SunEstimator* estimators[2] = {&sscnn, baseline};
  const int n_est = baseline ? 2 : 1;

  // Holds the diffraction cache (SpotCache::shared) for the whole report:
  // every sweep differs from the sensor only in its detector or anomalies.
  const Renderer cache_anchor(SensorInstance::draw(sensor, o.seed));

  // 1. Nominal test set.
  report("nominal test set: rendering", 0, 1);
  const Labelled nominal = render(sensor, o.test_images, o.seed, 1, o.threads);
  std::vector<EvalRecord> records[2];
  EvalSummary summaries[2];
  for (int e = 0; e < n_est; ++e) {
    report("nominal test set: " + names[e], e, n_est);
    records[e] = evaluate(*estimators[e], nominal);
    summaries[e] = summarize(records[e], estimators[e]->source(), 0.0);
  }
  double map_max = 0.0;
  for (int e = 0; e < n_est; ++e)
    for (bool alpha : {true, false}) {
      const auto errors = signedErrorsDeg(records[e], alpha);
      std::vector<double> abs_errors;
      for (double x : errors) abs_errors.push_back(std::abs(x));
      map_max = std::max(map_max, percentile(abs_errors, 0.95));
    }
  if (!(map_max > 0.0)) map_max = 1e-3;
  std::vector<std::string> pngs;
  auto save = [&](const std::string& name, const cv::Mat& image) {
    plot::writePng(dir + name, image);
    pngs.push_back(name);
  };
  const double a_max = sensor.fov.alpha_max_deg, b_max = sensor.fov.beta_max_deg;
  for (int e = 0; e < n_est; ++e)
    for (bool alpha : {true, false}) {
      const std::string axis = alpha ? "alpha" : "beta";
      plot::Axes axes{names[e] + ": mean |" + axis + " error| over the field of view", "alpha (deg)", "beta (deg)"};
      save("map_" + std::string(e ? "baseline" : "sscnn") + "_" + axis + ".png",
           plot::heatMap(axes, errorMap(records[e], sensor, o.map_bins, alpha), -a_max, a_max, -b_max, b_max, map_max,
                         "deg"));
    }
  {
    std::vector<std::pair<std::string, std::vector<double>>> samples;
    for (int e = 0; e < n_est; ++e)
      for (bool alpha : {true, false})
        samples.push_back({names[e] + (alpha ? " alpha" : " beta"), signedErrorsDeg(records[e], alpha)});
    save("error_histogram.png",
         plot::histograms({"error distribution (valid estimates)", "error (deg)", "fraction of images"}, samples,
                          -2 * map_max, 2 * map_max, 40));
    std::vector<plot::Series> series;
    for (int e = 0; e < n_est; ++e) {
      plot::Series s{names[e], {}, {}, false, true};
      for (const auto& r : records[e])
        if (r.estimate.valid)
          s.x.push_back(r.alpha_true_rad * kDegPerRad),
              s.y.push_back((r.estimate.alpha_rad - r.alpha_true_rad) * kDegPerRad);
      series.push_back(s);
    }
    save("error_vs_truth.png", plot::lines({"alpha error against true alpha", "true alpha (deg)", "error (deg)", false,
                                            -3 * map_max, 3 * map_max},
                                           series));
  }
  std::vector<double> ks;
  for (double k = 0.25; k <= 3.001; k += 0.25) ks.push_back(k);
  std::vector<double> ideal;
  for (double k : ks) ideal.push_back(std::erf(k / std::sqrt(2.0)));
  {
    std::vector<plot::Series> series{{"Gaussian ideal", ks, ideal, true, false, true}};
    for (int e = 0; e < n_est; ++e)
      for (bool alpha : {true, false})
        series.push_back({names[e] + (alpha ? " alpha" : " beta"), ks, reliability(records[e], alpha, ks)});
    save("reliability.png", plot::lines({"uncertainty calibration: errors within k predicted sigma", "k",
                                         "fraction of valid estimates", false, 0.0, 1.0},
                                        series));
  }

  // 2. Robustness sweeps (the SSCNN's validity screen is part of what is measured).
  const std::vector<Term> sweep = terms();
  std::vector<SweepResult> results(sweep.size());
  for (std::size_t t = 0; t < sweep.size(); ++t) {
    report("robustness sweeps", t, sweep.size());
    for (std::size_t l = 0; l < sweep[t].levels.size(); ++l) {
      SensorConfig c = sensor;
      sweep[t].apply(c, sweep[t].levels[l]);
      const Labelled data = render(c, o.sweep_images, o.seed + 1000 * (t + 1) + l, o.sweep_sensors, o.threads);
      for (int e = 0; e < 2; ++e) {
        if (e >= n_est) {
          results[t].mean_deg[e].push_back(NAN);
          results[t].valid[e].push_back(NAN);
          continue;
        }
        const EvalSummary summary = summarize(evaluate(*estimators[e], data), estimators[e]->source(), 0.0);
        results[t].mean_deg[e].push_back(summary.valid ? 0.5 * (summary.alpha.mean_deg + summary.beta.mean_deg) : NAN);
        results[t].valid[e].push_back(summary.valid_rate);
      }
    }
    std::vector<plot::Series> series;
    for (int e = 0; e < n_est; ++e)
      series.push_back({names[e] + " mean |error|", sweep[t].levels, results[t].mean_deg[e]});
    save("robustness_" + sweep[t].name + ".png",
         plot::lines({"robustness: " + sweep[t].label, sweep[t].label + " (" + sweep[t].unit + ")",
                      "mean |error| over valid estimates (deg)", true},
                     series, 480, 340));
  }
  report("robustness sweeps", sweep.size(), sweep.size());

  // 3. The published protocol: the model trained on it and the baseline on the
  // protocol's own images (no screens, as published).
  EvalSummary published_summaries[2];
  const int n_published = !published ? 0 : published->baseline ? 2 : 1;
  if (published) {
    if (!published->sscnn) throw std::invalid_argument("report: the published-protocol run has no SSCNN");
    report("published protocol: rendering", 0, 1);
    const Labelled data = render(published->sensor, o.published_images, o.published_grid_seed, 1, o.threads,
                                 SamplingMode::kGrid, o.published_grid_offset);
    SunEstimator* protocol_estimators[2] = {published->sscnn, published->baseline};
    for (int e = 0; e < n_published; ++e) {
      report("published protocol: " + names[e], e, n_published);
      published_summaries[e] =
          summarize(evaluate(*protocol_estimators[e], data), protocol_estimators[e]->source(), 0.0);
    }
  }

  // 4. Summary JSON.
  const double false_alarm = 1.0 - summaries[0].valid_rate;
  std::ostringstream js;
  js << "{\"sensor\": " << json::quoted(sensor.name) << ", \"seed\": " << o.seed
     << ", \"test_images\": " << o.test_images << ", \"sweep_images\": " << o.sweep_images;
  for (int e = 0; e < n_est; ++e) js << ", \"" << (e ? "baseline" : "sscnn") << "\": " << summaries[e].toJson();
  js << ", \"sscnn_false_alarm_rate\": " << json::number(false_alarm);
  js << ", \"reliability_k\": " << jsonArray(ks) << ", \"reliability_ideal\": " << jsonArray(ideal);
  for (int e = 0; e < n_est; ++e)
    for (bool alpha : {true, false})
      js << ", \"reliability_" << (e ? "baseline" : "sscnn") << "_" << (alpha ? "alpha" : "beta")
         << "\": " << jsonArray(reliability(records[e], alpha, ks));
  js << ", \"robustness\": [";
  for (std::size_t t = 0; t < sweep.size(); ++t) {
    js << (t ? ", " : "") << "{\"term\": " << json::quoted(sweep[t].name)
       << ", \"unit\": " << json::quoted(sweep[t].unit) << ", \"levels\": " << jsonArray(sweep[t].levels)
       << ", \"sscnn_mean_deg\": " << jsonArray(results[t].mean_deg[0])
       << ", \"sscnn_valid_rate\": " << jsonArray(results[t].valid[0])
       << ", \"baseline_mean_deg\": " << jsonArray(results[t].mean_deg[1])
       << ", \"baseline_valid_rate\": " << jsonArray(results[t].valid[1]) << "}";
  }
  js << "], \"published_sscnn\": {\"protocol\": \"far_field + grid, own test set\", \"sa_alpha_mean_deg\": 0.0053, "
        "\"sa_beta_mean_deg\": 0.0055, \"sa_alpha_max_deg\": 0.156, \"sa_beta_max_deg\": 0.145, "
        "\"ma_alpha_mean_deg\": 0.0055, \"ma_beta_mean_deg\": 0.0055, \"ma_alpha_max_deg\": 0.064, "
        "\"ma_beta_max_deg\": 0.085}";
  js << ", \"published_protocol\": ";
  if (published) {
    js << "{\"images\": " << o.published_images << ", \"grid_seed\": " << o.published_grid_seed
       << ", \"grid_offset\": " << o.published_grid_offset << ", \"sensor\": " << json::quoted(published->sensor.name)
       << ", \"sscnn_model\": " << json::quoted(o.published_sscnn_description)
       << ", \"baseline_calibration\": " << json::quoted(o.published_baseline_description);
    for (int e = 0; e < n_published; ++e)
      js << ", \"" << (e ? "baseline" : "sscnn") << "\": " << published_summaries[e].toJson();
    js << "}";
  } else {
    js << "null";
  }
  js << ", \"provenance\": {\"command\": " << json::quoted(o.command)
     << ", \"sensor_path\": " << json::quoted(o.sensor_path) << ", \"sscnn\": " << json::quoted(o.sscnn_description)
     << ", \"baseline\": " << json::quoted(o.baseline_description) << "}";
  js << ", \"plots\": [";
  for (std::size_t i = 0; i < pngs.size(); ++i) js << (i ? ", " : "") << json::quoted(pngs[i]);
  js << "]}";
  const std::string summary = js.str();
  writeFileAtomic(dir + "summary.json", summary + "\n");

  // 5. index.html.
  std::ostringstream h;
  h << "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>Credibility report: " << html(sensor.name)
    << "</title><style>body{font-family:sans-serif;max-width:1100px;margin:auto;padding:1em}"
       "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}"
       "img{margin:4px;border:1px solid #eee}pre{background:#f6f6f6;padding:8px;overflow:auto}</style></head><body>\n";
  h << "<h1>Credibility report: " << html(sensor.name) << "</h1>\n<p>SSCNN: " << html(o.sscnn_description)
    << "<br>Baseline: " << html(baseline ? o.baseline_description : "none")
    << "<br>Data: generated by this report, seed " << o.seed
    << "; machine-readable figures in <a href=\"summary.json\">summary.json</a>.</p>\n";
  h << "<h2>Accuracy on " << o.test_images
    << " nominal images (continuous random angles over the field of view)</h2>\n<table><tr><th>estimator</th><th>mean "
       "&alpha; / &beta; (deg)</th><th>RMS &alpha; / &beta;</th><th>max &alpha; / &beta;</th><th>valid</th><th>sub-FOV "
       "accuracy</th><th>within 1&sigma; &alpha; / &beta;</th><th>within 2&sigma;</th><th>within 3&sigma;</th></tr>\n";
  for (int e = 0; e < n_est; ++e) {
    const EvalSummary& s = summaries[e];
    h << "<tr><td>" << names[e] << "</td><td>" << fixed(s.alpha.mean_deg, 5) << " / " << fixed(s.beta.mean_deg, 5)
      << "</td><td>" << fixed(s.alpha.rms_deg, 5) << " / " << fixed(s.beta.rms_deg, 5) << "</td><td>"
      << fixed(s.alpha.max_deg, 4) << " / " << fixed(s.beta.max_deg, 4) << "</td><td>" << fixed(100 * s.valid_rate, 1)
      << " %</td><td>" << fixed(s.subfov_accuracy, 4) << "</td>";
    for (int k = 0; k < 3; ++k)
      h << "<td>" << fixed(100 * s.alpha_coverage.within[k], 1) << " / " << fixed(100 * s.beta_coverage.within[k], 1)
        << " %</td>";
    h << "</tr>\n";
  }
  h << "</table>\n";
  h << "<p>Ideal coverage for Gaussian errors: 68.3 / 95.4 / 99.7 %. SSCNN false-alarm rate (valid=false on nominal "
       "images): "
    << fixed(100 * false_alarm, 2) << " %.</p>\n";
  for (const auto& p : pngs)
    if (p.rfind("map_", 0) == 0) h << "<img src=\"" << p << "\" width=\"420\">";
  h << "\n<p><img src=\"error_histogram.png\" width=\"520\"><img src=\"error_vs_truth.png\" width=\"520\"></p>\n";
  h << "<h2>Uncertainty calibration</h2>\n<p><img src=\"reliability.png\" width=\"560\"></p>\n";
  h << "<h2>Robustness: each term swept from none to severe (" << o.sweep_images << " images, " << o.sweep_sensors
    << " sensors per level)</h2>\n<table><tr><th>term</th><th>levels</th><th>SSCNN mean |error| (deg)</th><th>SSCNN "
       "valid</th><th>baseline mean |error| (deg)</th><th>baseline valid</th></tr>\n";
  auto cells = [](const std::vector<double>& v, double scale, int digits) {
    std::string s;
    for (std::size_t i = 0; i < v.size(); ++i) s += (i ? " / " : "") + fixed(v[i] * scale, digits);
    return s;
  };
  for (std::size_t t = 0; t < sweep.size(); ++t)
    h << "<tr><td>" << html(sweep[t].label) << "</td><td>" << cells(sweep[t].levels, 1, 2) << " " << html(sweep[t].unit)
      << "</td><td>" << cells(results[t].mean_deg[0], 1, 5) << "</td><td>" << cells(results[t].valid[0], 100, 0)
      << " %</td><td>" << cells(results[t].mean_deg[1], 1, 5) << "</td><td>" << cells(results[t].valid[1], 100, 0)
      << " %</td></tr>\n";
  h << "</table>\n<p>The valid rate under severe conditions is the out-of-distribution flag rate: the SSCNN's screens "
       "(saturation, predicted sigma, field of view) or the baseline's own checks.</p>\n<p>";
  for (const auto& p : pngs)
    if (p.rfind("robustness_", 0) == 0) h << "<img src=\"" << p << "\" width=\"360\">";
  h << "</p>\n<h2>The published SSCNN and the published protocol</h2>\n<p>Published figures: far-field optics of the "
       "pinhole, spot centres on the pixel grid, noisy thresholded images, each network on its own test set. ";
  if (published)
    h << "Beside them, a model trained on that protocol (" << html(o.published_sscnn_description)
      << ") and the baseline (" << html(published->baseline ? o.published_baseline_description : "none") << ") on "
      << o.published_images << " grid positions its training never saw (seed " << o.published_grid_seed
      << " from position " << o.published_grid_offset << "), without screens, as published.";
  else
    h << "No published-protocol model was given (scripts/train_published.sh makes one for thesis_sa and thesis_ma; "
         "the published work has no wide-field sensor).";
  h << "</p>\n<table><tr><th>estimator</th><th>mean &alpha; / &beta; (deg)</th><th>RMS &alpha; / &beta;</th><th>max "
       "&alpha; / &beta;</th><th>valid</th></tr>\n";
  for (int e = 0; e < n_published; ++e) {
    const EvalSummary& s = published_summaries[e];
    h << "<tr><td>" << names[e] << ", published protocol</td><td>" << fixed(s.alpha.mean_deg, 5) << " / "
      << fixed(s.beta.mean_deg, 5) << "</td><td>" << fixed(s.alpha.rms_deg, 5) << " / " << fixed(s.beta.rms_deg, 5)
      << "</td><td>" << fixed(s.alpha.max_deg, 4) << " / " << fixed(s.beta.max_deg, 4) << "</td><td>"
      << fixed(100 * s.valid_rate, 1) << " %</td></tr>\n";
  }
  h << "<tr><td>published SSCNN, single aperture</td><td>0.0053 / 0.0055</td><td>0.0076 / 0.0081</td><td>0.156 / "
       "0.145</td><td>&mdash;</td></tr>\n<tr><td>published SSCNN, multi-aperture</td><td>0.0055 / "
       "0.0055</td><td>0.0073 "
       "/ 0.0074</td><td>0.064 / 0.085</td><td>&mdash;</td></tr></table>\n";
  h << "<h2>Provenance</h2>\n<pre>command: " << html(o.command) << "\nsensor config: " << html(o.sensor_path) << "\n\n"
    << html(toYaml(sensor)) << "\n\nmodel metadata:\n"
    << html(o.model_metadata_yaml) << "</pre>\n</body></html>\n";
  writeFileAtomic(dir + "index.html", h.str());
  replaceDirectory(staged, out.string());
  return summary;
}

}  // namespace dss
