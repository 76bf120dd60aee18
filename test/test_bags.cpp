// The dss command line end to end. generate: bags that rosbag reads,
// identical for the same seed, clear errors for bad arguments and configs, no
// partial files left. bench infer/train: one JSON line with every figure.
// calibrate-unit: a drawn unit calibrated from the shipped family model.
#include <digital_sun_sensor/SpotCentres.h>
#include <digital_sun_sensor/SunAngles.h>
#include <geometry_msgs/Vector3Stamped.h>
#include <gtest/gtest.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/Image.h>
#include <std_msgs/String.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <functional>
#include <sstream>
#include <string>
#include <vector>

#include "digital_sun_sensor/common/estimate_status.h"
#include "digital_sun_sensor/ros/bag_io.h"
#include "digital_sun_sensor/ros/conversions.h"

namespace {

struct Result {
  int code;
  std::string output;
};

Result run(const std::string& args) {
  const std::string cmd = std::string(DSS_BINARY) + " " + args + " 2>&1";
  FILE* pipe = popen(cmd.c_str(), "r");
  std::string out;
  std::array<char, 4096> buf;
  while (pipe && fgets(buf.data(), buf.size(), pipe)) out += buf.data();
  const int status = pipe ? pclose(pipe) : -1;
  return {WIFEXITED(status) ? WEXITSTATUS(status) : -1, out};
}

std::string slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

bool exists(const std::string& path) { return access(path.c_str(), F_OK) == 0; }

std::string tmp(const std::string& name) { return "/tmp/dss_test_" + std::to_string(getpid()) + "_" + name; }

const std::string kSensor = std::string(DSS_SOURCE_DIR) + "/config/sensors/thesis_sa.yaml";

TEST(Generate, WritesReadableBagAndSameSeedGivesIdenticalBytes) {
  const std::string a = tmp("a.bag"), b = tmp("b.bag"), c = tmp("c.bag");
  const std::string base = "generate --sensor " + kSensor + " --count 5 --out ";
  auto ra = run(base + a + " --seed 3 --threads 2");
  ASSERT_EQ(ra.code, 0) << ra.output;
  ASSERT_EQ(run(base + b + " --seed 3 --threads 1").code, 0);
  ASSERT_EQ(run(base + c + " --seed 4").code, 0);
  EXPECT_EQ(slurp(a), slurp(b)) << "same seed must give the same bag, whatever the thread count";
  EXPECT_NE(slurp(a), slurp(c));
  EXPECT_FALSE(exists(a + ".partial"));

  rosbag::Bag bag(a, rosbag::bagmode::Read);
  int images = 0, truths = 0, spots = 0, infos = 0;
  std::vector<ros::Time> image_stamps, truth_stamps;
  for (const rosbag::MessageInstance& m : rosbag::View(bag)) {
    if (auto img = m.instantiate<sensor_msgs::Image>()) {
      ++images;
      EXPECT_EQ(m.getTopic(), "/sun_sensor/image");
      EXPECT_EQ(img->encoding, "mono8");
      EXPECT_EQ(img->width, 512u);
      EXPECT_EQ(img->data.size(), 512u * 512u);
      EXPECT_EQ(img->header.frame_id, "sun_sensor_link");
      image_stamps.push_back(img->header.stamp);
    } else if (auto t = m.instantiate<digital_sun_sensor::SunAngles>()) {
      ++truths;
      EXPECT_EQ(m.getTopic(), "/sun_sensor/truth");
      EXPECT_EQ(t->source, "truth");
      EXPECT_TRUE(t->valid);
      truth_stamps.push_back(t->header.stamp);
    } else if (m.instantiate<digital_sun_sensor::SpotCentres>()) {
      ++spots;
    } else if (auto info = m.instantiate<std_msgs::String>()) {
      ++infos;
      EXPECT_NE(info->data.find("thesis_sa"), std::string::npos);
      EXPECT_NE(info->data.find("seed: 3"), std::string::npos);
    }
  }
  EXPECT_EQ(images, 5);
  EXPECT_EQ(truths, 5);
  EXPECT_EQ(spots, 5);
  EXPECT_EQ(infos, 1);
  EXPECT_EQ(image_stamps, truth_stamps);
  for (const auto& f : {a, b, c}) std::remove(f.c_str());
}

TEST(Generate, BadInputGetsClearErrors) {
  const std::string out = tmp("bad.bag");
  auto r = run("generate --sensor " + kSensor + " --count 2 --seed 1 --out " + out + " --bogus 1");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.output.find("unknown option --bogus"), std::string::npos) << r.output;
  r = run("generate --sensor " + kSensor + " --count two --seed 1 --out " + out);
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.output.find("--count expects an integer"), std::string::npos) << r.output;
  r = run("generate --sensor " + kSensor + " --seed 1 --out " + out);
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.output.find("missing required --count"), std::string::npos) << r.output;
  r = run("generate --sensor " + kSensor + " --count 2 --seed 1 --out " + out + " --set mask.height_mm=-1");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.output.find("mask.height_mm"), std::string::npos) << r.output;
  r = run("generate --sensor " + kSensor + " --count 2 --seed 1 --out " + out + " --anomalies lava=1");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.output.find("unknown anomaly 'lava'"), std::string::npos) << r.output;
  r = run("generate --sensor " + kSensor + " --count 2 --seed 1 --out /nonexistent_dir/x.bag");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.output.find("/nonexistent_dir/x.bag"), std::string::npos) << r.output;
  EXPECT_FALSE(exists(out));
  EXPECT_FALSE(exists(out + ".partial"));
  // calibrate-sigma refuses a bad correction degree before it reads any bag.
  for (const std::string degree : {"25", "cubic"}) {
    r = run("calibrate-sigma --model models/thesis_sa.dssmodel --data /nonexistent_dir/x.bag --out " + out +
            " --correction-degree " + degree);
    EXPECT_EQ(r.code, 2) << r.output;
    EXPECT_NE(r.output.find("--correction-degree"), std::string::npos) << r.output;
    EXPECT_EQ(r.output.find("/nonexistent_dir/x.bag"), std::string::npos) << r.output;
  }
  // A spot bias of a degree out of range, or for a model without a geometric head.
  for (const std::string model :
       {"thesis_sa_family.dssmodel --spot-bias-degree 25", "thesis_sa.dssmodel --spot-bias-degree 2"}) {
    r = run("calibrate-sigma --model models/" + model + " --data /nonexistent_dir/x.bag --out " + out);
    EXPECT_EQ(r.code, 2) << r.output;
    EXPECT_NE(r.output.find("--spot-bias-degree"), std::string::npos) << r.output;
    EXPECT_EQ(r.output.find("/nonexistent_dir/x.bag"), std::string::npos) << r.output;
  }
  // calibrate-height: a spot bias degree out of range, before any bag is read.
  r =
      run("calibrate-height --model models/wide_ma_family.dssmodel --data /nonexistent_dir/x.bag "
          "--height-change-um 10 --spot-bias-degree 25 --out " +
          out);
  EXPECT_EQ(r.code, 2) << r.output;
  EXPECT_NE(r.output.find("--spot-bias-degree"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("/nonexistent_dir/x.bag"), std::string::npos) << r.output;
  // And a symmetry that is unknown, or that the model's sensor lacks.
  r = run("calibrate-sigma --model models/thesis_sa.dssmodel --data /nonexistent_dir/x.bag --out " + out +
          " --symmetry mirror");
  EXPECT_EQ(r.code, 2) << r.output;
  EXPECT_NE(r.output.find("--symmetry"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("/nonexistent_dir/x.bag"), std::string::npos) << r.output;
  r = run("calibrate-sigma --model models/thesis_ca.dssmodel --data /nonexistent_dir/x.bag --out " + out +
          " --symmetry flips");
  EXPECT_EQ(r.code, 2) << r.output;
  EXPECT_NE(r.output.find("sensor 'thesis_ca' lacks that symmetry: aperture"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("/nonexistent_dir/x.bag"), std::string::npos) << r.output;
  // A geometric head (wide_ma's) solves through its own geometry: no mirror average.
  r = run("calibrate-sigma --model models/wide_ma.dssmodel --data /nonexistent_dir/x.bag --out " + out +
          " --symmetry flips");
  EXPECT_EQ(r.code, 2) << r.output;
  EXPECT_NE(r.output.find("the geometric head solves through the sensor's own geometry"), std::string::npos)
      << r.output;
  EXPECT_EQ(r.output.find("/nonexistent_dir/x.bag"), std::string::npos) << r.output;
  EXPECT_FALSE(exists(out));
  // So does eval a bad spike threshold for its screen, or a symmetry it does not choose.
  r = run("eval --estimator sscnn:models/thesis_sa.dssmodel --data /nonexistent_dir/x.bag --screen --spike-sigmas -1");
  EXPECT_EQ(r.code, 2) << r.output;
  EXPECT_NE(r.output.find("--spike-sigmas"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("/nonexistent_dir/x.bag"), std::string::npos) << r.output;
  r = run("eval --estimator sscnn:models/thesis_sa.dssmodel --data /nonexistent_dir/x.bag --symmetry dihedral");
  EXPECT_EQ(r.code, 2) << r.output;
  EXPECT_NE(r.output.find("--symmetry: inference symmetry must be 'model'"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("/nonexistent_dir/x.bag"), std::string::npos) << r.output;
  r = run("--help");
  EXPECT_EQ(r.code, 0);
  EXPECT_NE(r.output.find("generate"), std::string::npos);
  r = run("generate --help");
  EXPECT_EQ(r.code, 0);
  EXPECT_NE(r.output.find("--sampling"), std::string::npos);
}

// The figure after "key": in a JSON line (NaN when absent or null).
double jsonNumber(const std::string& line, const std::string& key) {
  const auto at = line.find("\"" + key + "\": ");
  if (at == std::string::npos || line.compare(at + key.size() + 4, 4, "null") == 0) return std::nan("");
  return std::stod(line.substr(at + key.size() + 4));
}

// The fields of one row of dss eval's CSV (a quoted status detail may hold
// commas and then spans several: count from the end past the status).
std::vector<std::string> csvFields(const std::string& row) {
  std::vector<std::string> fields;
  std::istringstream cells(row);
  for (std::string cell; std::getline(cells, cell, ',');) fields.push_back(cell);
  return fields;
}

// The data rows of dss eval's CSV at `path` (the header left out).
std::vector<std::string> csvRows(const std::string& path) {
  std::istringstream lines(slurp(path));
  std::vector<std::string> rows;
  std::string row;
  std::getline(lines, row);  // header
  while (std::getline(lines, row)) rows.push_back(row);
  return rows;
}

std::string lastLine(const std::string& output, const std::string& prefix) {
  const auto at = output.rfind(prefix);
  return at == std::string::npos ? "" : output.substr(at, output.find('\n', at) - at);
}

// Calibrate on one bag, evaluate on a disjoint bag of the same simulated
// sensor (same seed, later offset): one JSON line with every evaluation key of docs/design.md.
TEST(Baseline, CalibrateThenEvalPrintsEveryKey) {
  const std::string cal = tmp("cal.bag"), test = tmp("test.bag"), calib = tmp("calib.yaml"), csv = tmp("eval.csv");
  ASSERT_EQ(run("generate --sensor " + kSensor +
                " --count 80 --seed 5 --anomalies as_built=1 --set optics.psf_node_step_deg=3 --out " + cal)
                .code,
            0);
  ASSERT_EQ(
      run("generate --sensor " + kSensor +
          " --count 30 --seed 5 --offset 80 --anomalies as_built=1 --set optics.psf_node_step_deg=3 --out " + test)
          .code,
      0);
  auto r = run("calibrate --data " + cal + " --out " + calib);
  ASSERT_EQ(r.code, 0) << r.output;
  const std::string fit = lastLine(r.output, "{\"images\"");
  EXPECT_EQ(jsonNumber(fit, "images"), 80);
  EXPECT_LT(jsonNumber(fit, "rms_px_fitted"), 0.5) << fit;
  EXPECT_EQ(jsonNumber(fit, "field_ninths_empty"), 0) << fit;  // 80 images over the field
  r = run("eval --data " + test + " --estimator centroid:" + calib + " --csv " + csv + " --crlb-samples 5");
  ASSERT_EQ(r.code, 0) << r.output;
  const std::string line = lastLine(r.output, "{\"estimator\"");
  for (const char* key :
       {"n", "alpha_mean_deg", "alpha_rms_deg", "alpha_p99_deg", "alpha_max_deg", "beta_mean_deg", "beta_rms_deg",
        "beta_p99_deg", "beta_max_deg", "subfov_accuracy", "valid_rate", "ms_per_image", "crlb_ratio"}) {
    EXPECT_FALSE(std::isnan(jsonNumber(line, key))) << key << " in " << line;
  }
  EXPECT_EQ(jsonNumber(line, "n"), 30);
  EXPECT_GT(jsonNumber(line, "valid_rate"), 0.8);
  EXPECT_LT(jsonNumber(line, "alpha_mean_deg"), 0.005) << line;  // the published SSCNN: 0.0053
  EXPECT_GT(jsonNumber(line, "crlb_ratio"), 1.0) << line;        // nothing beats the bound
  const std::string text = slurp(csv);
  EXPECT_EQ(std::count(text.begin(), text.end(), '\n'), 31);
  // The bound on every 6th image (30 images, 5 samples), the answered ones
  // among them: the same images whichever estimator runs.
  const std::vector<std::string> rows = csvRows(csv);
  int bounded = 0, answered_picks = 0;
  for (int index = 0; index < static_cast<int>(rows.size()); ++index) {
    const std::string& row = rows[static_cast<std::size_t>(index)];
    const std::vector<std::string> fields = csvFields(row);
    ASSERT_GE(fields.size(), 16u) << row;
    const bool has_bound = fields[fields.size() - 2] != "nan";
    bounded += has_bound;
    answered_picks += index % 6 == 0 && fields[10] == "1";
    if (has_bound) {
      EXPECT_EQ(index % 6, 0) << row;
    }
  }
  EXPECT_EQ(bounded, answered_picks);
  EXPECT_EQ(jsonNumber(line, "crlb_samples"), bounded);
  for (const auto& f : {cal, test, calib, csv}) std::remove(f.c_str());
}

// What a user does with a built thesis_ma unit and the shipped family model:
// uncalibrated, every estimate is flagged model_mismatch or holds its error
// within 3 sigma; calibrated from 25 lab images (dss calibrate-unit), it
// comes back near the family model's accuracy on the design (0.000516 deg on
// 2000 images). The unit (seed 9616) is one no figure was tuned on.
TEST(CalibrateUnit, ShippedFamilyModelCalibratesADrawnUnit) {
  const std::string lab = tmp("unit_lab.bag"), test = tmp("unit_test.bag"), unit = tmp("unit.dssmodel"),
                    csv = tmp("unit.csv");
  const std::string family = std::string(DSS_SOURCE_DIR) + "/models/thesis_ma_family.dssmodel";
  const std::string draw = "generate --sensor " + std::string(DSS_SOURCE_DIR) +
                           "/config/sensors/thesis_ma.yaml --anomalies as_built=1 "
                           "--set as_built.aperture_diameter_sigma_um=0 --seed 9616";
  ASSERT_EQ(run(draw + " --count 25 --out " + lab).code, 0);
  ASSERT_EQ(run(draw + " --count 100 --offset 100000 --out " + test).code, 0);

  auto r = run("eval --data " + test + " --estimator sscnn:" + family + " --crlb-samples 0 --csv " + csv);
  ASSERT_EQ(r.code, 0) << r.output;
  int images = 0, flagged = 0, within_3_sigma = 0;
  for (const std::string& row : csvRows(csv)) {
    ++images;
    if (row.find("model_mismatch") != std::string::npos) {
      ++flagged;
      continue;
    }
    const std::vector<std::string> f = csvFields(row);  // errors, then sigmas: columns 6-9
    within_3_sigma +=
        std::abs(std::stod(f[6])) <= 3.0 * std::stod(f[8]) && std::abs(std::stod(f[7])) <= 3.0 * std::stod(f[9]);
  }
  std::printf("uncalibrated unit: %d of %d images flagged model_mismatch, %d others within 3 sigma\n", flagged, images,
              within_3_sigma);
  EXPECT_EQ(images, 100);
  EXPECT_GE(flagged + within_3_sigma, 95);

  // Five lab images leave at least four ninths of the field without one: said.
  r = run("calibrate-unit --model " + family + " --data " + lab + " --max-images 5 --out " + unit);
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_GE(jsonNumber(lastLine(r.output, "{\"command\""), "field_ninths_empty"), 4.0) << r.output;
  EXPECT_NE(r.output.find("note: the 5 lab images leave"), std::string::npos) << r.output;

  r = run("calibrate-unit --model " + family + " --data " + lab + " --out " + unit);
  ASSERT_EQ(r.code, 0) << r.output;
  r = run("eval --data " + test + " --estimator sscnn:" + unit + " --crlb-samples 0");
  ASSERT_EQ(r.code, 0) << r.output;
  const std::string line = lastLine(r.output, "{\"estimator\"");
  std::printf("calibrated from 25 images: %s\n", line.c_str());
  EXPECT_GE(jsonNumber(line, "valid_rate"), 0.95) << line;
  EXPECT_LT(jsonNumber(line, "alpha_mean_deg"), 1.3 * 0.000516) << line;
  EXPECT_LT(jsonNumber(line, "beta_mean_deg"), 1.3 * 0.000526) << line;

  // The unit's mask then rises 20 um, which moves every spot alike. Replayed
  // with references, as calibration_node runs: before the first refit its
  // estimates, read with the calibrated sigma, are widened once ten
  // references disagree with them.
  const std::string drifted = tmp("unit_drifted.bag"), replay = tmp("replay.csv"), recalibrated = tmp("recal.dssmodel");
  ASSERT_EQ(run(draw + " --set mask.height_mm=5.02 --count 60 --offset 200000 --out " + drifted).code, 0);
  r = run("recalibrate --model " + unit + " --data " + drifted + " --min-pairs 40 --refit-every 10 --out " +
          recalibrated + " --csv " + replay);
  ASSERT_EQ(r.code, 0) << r.output;
  const std::string replayed = lastLine(r.output, "{\"command\"");
  std::printf("drifted unit replayed: %s\n", replayed.c_str());
  EXPECT_GE(jsonNumber(replayed, "refits"), 1.0) << replayed;
  EXPECT_LT(jsonNumber(replayed, "within_3sigma_before_first_refit"), 0.2) << replayed;
  EXPECT_GT(jsonNumber(replayed, "within_3sigma_widened_before_first_refit"), 0.7) << replayed;
  EXPECT_EQ(csvRows(replay).size(), 60u);
  for (const auto& f : {lab, test, unit, csv, drifted, replay, recalibrated}) std::remove(f.c_str());
}

// calibrate-sigma with --sigma keep --spot-mismatch keep (how a family recipe's
// stray-lit sigma bag is used) covers the images by the input envelope and
// changes nothing else: the estimates and sigma on them stay to the digit.
TEST(CalibrateSigma, KeepingSigmaAndMismatchWidensTheEnvelopeOnly) {
  const std::string bag = tmp("stray.bag"), widened = tmp("widened.dssmodel"), out = tmp("refused.dssmodel");
  const std::string family = std::string(DSS_SOURCE_DIR) + "/models/thesis_sa_family.dssmodel";
  ASSERT_EQ(run("generate --sensor " + std::string(DSS_SOURCE_DIR) +
                "/config/sensors/thesis_sa.yaml --anomalies stray_light=1 --count 12 --seed 612 --out " + bag)
                .code,
            0);
  auto r = run("calibrate-sigma --model " + family + " --data " + bag + " --sigma keep --spot-mismatch keep --out " +
               widened);
  ASSERT_EQ(r.code, 0) << r.output;
  const std::string line = lastLine(r.output, "{\"command\"");
  EXPECT_NE(line.find("\"sigma_mode\": \"kept\""), std::string::npos) << line;
  EXPECT_EQ(line.find("scale_alpha"), std::string::npos) << line;
  std::vector<std::vector<std::string>> rows[2];
  int k = 0;
  for (const auto& model : {family, widened}) {
    const std::string csv = tmp("widened" + std::to_string(k) + ".csv");
    ASSERT_EQ(run("eval --data " + bag + " --estimator sscnn:" + model + " --crlb-samples 0 --csv " + csv).code, 0);
    for (const std::string& row : csvRows(csv)) rows[k].push_back(csvFields(row));
    std::remove(csv.c_str());
    ++k;
  }
  ASSERT_EQ(rows[0].size(), 12u);
  ASSERT_EQ(rows[1].size(), 12u);
  for (std::size_t i = 0; i < rows[0].size(); ++i) {
    for (int column = 4; column <= 9; ++column)  // estimates, errors, sigmas
      EXPECT_EQ(rows[0][i][column], rows[1][i][column]) << "image " << i << ", column " << column;
    EXPECT_EQ(rows[1][i][10], "1") << "image " << i;  // valid: within the envelope
  }
  for (const std::string mode : {"--sigma sometimes", "--spot-mismatch fit"}) {
    r = run("calibrate-sigma --model " + family + " --data " + bag + " " + mode + " --out " + out);
    EXPECT_EQ(r.code, 2) << r.output;
    EXPECT_NE(r.output.find(mode.substr(0, mode.find(' '))), std::string::npos) << r.output;
  }
  EXPECT_FALSE(exists(out));
  // A spot bias fitted on the same images: recorded, and the model reads them.
  const std::string biased = tmp("biased.dssmodel"), biased_csv = tmp("biased.csv");
  r = run("calibrate-sigma --model " + family + " --data " + bag +
          " --spot-bias-degree 2 --sigma keep --spot-mismatch keep --out " + biased);
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(lastLine(r.output, "{\"command\"").find("\"spot_bias_rms_um_after\""), std::string::npos) << r.output;
  ASSERT_EQ(run("eval --data " + bag + " --estimator sscnn:" + biased + " --crlb-samples 0 --csv " + biased_csv).code,
            0);
  EXPECT_EQ(csvRows(biased_csv).size(), 12u);
  for (const auto& f : {bag, widened, biased, biased_csv}) std::remove(f.c_str());
}

// dss train on a small bag writes a model that dss eval runs as sscnn:MODEL;
// a too-short time limit stops with a checkpoint (exit 3) that --resume
// finishes; bad options and mismatched checkpoints are refused.
TEST(Train, TrainThenEvalAndResume) {
  const std::string bag = tmp("train.bag"), model = tmp("model.dssm"), ckpt = tmp("model.ckpt");
  ASSERT_EQ(
      run("generate --sensor " + kSensor + " --count 96 --seed 6 --set optics.psf_node_step_deg=3 --out " + bag).code,
      0);
  const std::string common = "train --data " + bag + " --out " + model + " --arch resnet10_w16 --batch 16 --epochs 2";
  auto r = run(common + " --checkpoint " + ckpt + " --max-minutes 0.00001");
  EXPECT_EQ(r.code, 3) << r.output;
  EXPECT_NE(r.output.find("\"stop\": \"time_limit\""), std::string::npos) << r.output;
  EXPECT_FALSE(exists(model));
  EXPECT_TRUE(exists(ckpt));
  r = run(common + " --resume " + ckpt);
  ASSERT_EQ(r.code, 0) << r.output;
  const std::string line = lastLine(r.output, "{\"command\"");
  EXPECT_EQ(jsonNumber(line, "epochs_completed"), 2) << line;
  EXPECT_LT(jsonNumber(line, "val_alpha_mean_deg"), 0.1) << line;
  EXPECT_NE(r.output.find("epoch 2/2 done"), std::string::npos) << r.output;
  ASSERT_TRUE(exists(model));
  r = run("eval --data " + bag + " --estimator sscnn:" + model + " --crlb-samples 0");
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_EQ(jsonNumber(lastLine(r.output, "{\"estimator\""), "n"), 96);
  // The finished checkpoint resumed again (a script rerun after its model
  // file was removed) writes the same model, and says that it is trained
  // and how it validated.
  std::remove(model.c_str());
  r = run(common + " --resume " + ckpt);
  ASSERT_EQ(r.code, 0) << r.output;
  const std::string again = lastLine(r.output, "{\"command\"");
  EXPECT_EQ(jsonNumber(again, "epochs_completed"), 2) << r.output;
  for (const char* key : {"val_alpha_mean_deg", "val_beta_max_deg", "best_val_mean_deg", "best_epoch"}) {
    EXPECT_GT(jsonNumber(again, key), 0.0) << key << ": " << again;
    EXPECT_NEAR(jsonNumber(again, key), jsonNumber(line, key), 1e-6 * jsonNumber(line, key)) << key;
  }
  ASSERT_TRUE(exists(model));
  EXPECT_NE(slurp(model).find("epochs_completed: 2\n"), std::string::npos);  // the file's training summary (text)

  r = run(common + " --resume " + ckpt + " --seed 9");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.output.find("seed"), std::string::npos) << r.output;
  r = run(common + " --augment noise=0.3");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.output.find("unknown augmentation 'noise'"), std::string::npos) << r.output;
  r = run(common + " --val-fraction 1.5");
  EXPECT_EQ(r.code, 2);
  for (const auto& f : {bag, model, ckpt}) std::remove(f.c_str());
}

// Unusable data is refused with a message naming the file and the problem.
TEST(Baseline, BadBagsGetClearErrors) {
  const std::string empty = tmp("empty.bag"), junk = tmp("junk.bag"), good = tmp("good.bag"), cut = tmp("cut.bag"),
                    other = tmp("other.bag"), small = tmp("small.bag"), calib = tmp("bad_calib.yaml");
  { std::ofstream touch(empty); }
  { std::ofstream(junk) << std::string(5000, 'x'); }
  ASSERT_EQ(
      run("generate --sensor " + kSensor + " --count 30 --seed 3 --set optics.psf_node_step_deg=3 --out " + good).code,
      0);
  const std::string bytes = slurp(good);
  { std::ofstream(cut, std::ios::binary) << bytes.substr(0, bytes.size() / 2); }
  {
    rosbag::Bag bag(other, rosbag::bagmode::Write);
    std_msgs::String s;
    s.data = "hello";
    bag.write("/chatter", ros::Time(1, 0), s);
  }
  ASSERT_EQ(run("generate --sensor " + kSensor +
                " --count 3 --seed 3 --set optics.psf_node_step_deg=3 --set detector.width_px=256 --set "
                "detector.height_px=256 --out " +
                small)
                .code,
            0);
  ASSERT_EQ(run("calibrate --data " + good + " --out " + calib).code, 0);
  const std::string two_units = tmp("two_units.bag");
  ASSERT_EQ(run("generate --sensor " + kSensor +
                " --count 2 --instances 2 --seed 3 --set optics.psf_node_step_deg=3 --out " + two_units)
                .code,
            0);

  for (const auto& bag : {empty, junk, cut}) {
    const auto r = run("eval --data " + bag + " --estimator centroid:" + calib);
    EXPECT_EQ(r.code, 1) << bag;
    EXPECT_NE(r.output.find(bag), std::string::npos) << r.output;
  }
  auto r = run("calibrate --data " + other + " --out " + tmp("never.yaml"));
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.output.find("has no messages on /sun_sensor/image (topics in it: /chatter)"), std::string::npos)
      << r.output;
  EXPECT_FALSE(exists(tmp("never.yaml")));
  r = run("eval --data " + small + " --estimator centroid:" + calib);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.output.find("is 256x256 mono8 but the sensor 'thesis_sa' is 512x512 mono8"), std::string::npos)
      << r.output;
  // The bound of "the" unit needs a bag of one unit.
  r = run("eval --data " + two_units + " --estimator centroid:" + calib + " --crlb-sensor unit");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.output.find("rendered from 2 sensor instances, not one"), std::string::npos) << r.output;
  r = run("eval --data " + good + " --estimator centroid:/nonexistent/calib.yaml");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.output.find("/nonexistent/calib.yaml"), std::string::npos) << r.output;
  r = run("eval --data " + good + " --estimator magic:" + calib);
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.output.find("sscnn:MODEL, centroid:CALIB or pattern:SENSOR_CONFIG"), std::string::npos) << r.output;
  r = run("eval --data " + good + " --estimator sscnn:" + calib);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.output.find(calib), std::string::npos) << r.output;
  // A unit calibration needs a model with a geometric head.
  r = run("calibrate-unit --model " + std::string(DSS_SOURCE_DIR) + "/models/thesis_sa.dssmodel --data " + good +
          " --out " + tmp("never.dssmodel"));
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.output.find("has no geometric head"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("models/thesis_sa_family.dssmodel"), std::string::npos) << r.output;  // where to go instead
  EXPECT_FALSE(exists(tmp("never.dssmodel")));
  for (const auto& f : {empty, junk, good, cut, other, small, calib, two_units}) std::remove(f.c_str());
}

// The JSON line carries each key with a positive number.
void expectPositiveFigures(const std::string& output, const std::vector<std::string>& keys) {
  const auto line = output.substr(output.rfind("{\"bench\""));
  for (const auto& key : keys) {
    const auto at = line.find("\"" + key + "\":");
    ASSERT_NE(at, std::string::npos) << key << " missing in " << line;
    EXPECT_GT(std::stod(line.substr(at + key.size() + 3)), 0.0) << key << " in " << line;
  }
}

TEST(Bench, InferAndTrainPrintOneJsonLine) {
  auto r = run("bench infer --sensor " + kSensor + " --arch resnet10_w16 --count 4 --dense-count 1");
  ASSERT_EQ(r.code, 0) << r.output;
  expectPositiveFigures(r.output,
                        {"parameters", "mean_active_sites", "sparse_median_ms", "sparse_p99_ms", "sparse_cpu_median_ms",
                         "sparse_network_median_ms", "dense_median_ms", "dense_p99_ms", "dense_over_sparse"});
  r = run("bench train --sensor " + kSensor + " --arch resnet10_w16 --batch 4 --steps 2 --images 8");
  ASSERT_EQ(r.code, 0) << r.output;
  expectPositiveFigures(r.output, {"parameters", "ms_per_step", "images_per_s", "mean_active_sites"});
  r = run("bench infer --sensor " + kSensor + " --arch resnet99");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.output.find("unknown architecture 'resnet99' (available: resnet34"), std::string::npos) << r.output;
  r = run("bench infer --sensor " + kSensor + " --model /nonexistent.dssmodel");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.output.find("cannot open '/nonexistent.dssmodel'"), std::string::npos) << r.output;
}

// Lab truth as a sun vector (geometry_msgs/Vector3Stamped) is read as
// angles when it is in the sensor frame (or names none), and skipped with a
// reason in another frame.
TEST(Messages, SunVectorTruthIsReadInTheSensorFrameOnly) {
  const std::string path = tmp("vector_truth.bag");
  const std::vector<std::string> frames = {"sun_sensor_link", "", "base_link"};
  {
    rosbag::Bag bag(path, rosbag::bagmode::Write);
    for (std::size_t i = 0; i < frames.size(); ++i) {
      sensor_msgs::Image image;
      image.header.stamp = ros::Time(1.0 + i);
      image.encoding = "mono8";
      image.width = image.height = image.step = 4;
      image.data.assign(16, 7);
      bag.write("/lab/image", image.header.stamp, image);
      geometry_msgs::Vector3Stamped sun;
      sun.header.stamp = image.header.stamp;
      sun.header.frame_id = frames[i];
      sun.vector.x = 0.1 * (i + 1);
      sun.vector.y = -0.05;
      sun.vector.z = 2.0;
      bag.write("/lab/sun", sun.header.stamp, sun);
    }
  }
  dss::DatasetTopics topics;
  topics.image = "/lab/image";
  topics.truth = "/lab/sun";
  std::vector<dss::LabelledImage> read;
  const dss::BagReadStats stats = dss::DatasetBagReader({path}, topics).forEach([&](const dss::LabelledImage& item) {
    read.push_back(item);
    return true;
  });
  ASSERT_EQ(read.size(), 2u);
  EXPECT_DOUBLE_EQ(read[0].truth.alpha, std::atan2(0.1, 2.0));
  EXPECT_DOUBLE_EQ(read[1].truth.alpha, std::atan2(0.2, 2.0));
  EXPECT_DOUBLE_EQ(read[1].truth.beta, std::atan2(-0.05, 2.0));
  EXPECT_TRUE(read[0].truth.valid);
  EXPECT_EQ(read[0].truth.subfov_class, digital_sun_sensor::SunAngles::SUBFOV_UNKNOWN);
  EXPECT_EQ(stats.bad_truths, 1u);
  EXPECT_NE(stats.first_bad_truth.find("base_link"), std::string::npos) << stats.first_bad_truth;
  EXPECT_EQ(stats.unmatched_images, 1u);
  std::remove(path.c_str());
}

}  // namespace

// The message's STATUS_* constants and the core's codes are one list.
// Malformed images mixed into a bag (what dss train, calibrate, eval and
// trainer_node read): each is skipped with a count and a reason, the good
// pairs are all read, and nothing else is disturbed.
TEST(Messages, MalformedImagesInABagAreSkippedAndCounted) {
  const std::string path = tmp("mixed.bag");
  std::vector<std::function<void(sensor_msgs::Image&)>> damage = {
      [](sensor_msgs::Image&) {},                                // good
      [](sensor_msgs::Image& m) { m.encoding = "rgb8"; },        // wrong encoding
      [](sensor_msgs::Image& m) { m.data.resize(3); },           // short buffer
      [](sensor_msgs::Image& m) { m.width = 0; },                // zero width
      [](sensor_msgs::Image& m) { m.width = m.step = 100000; },  // over the size limit
      [](sensor_msgs::Image& m) { m.step = 1; },                 // row step shorter than a row
  };
  {
    rosbag::Bag bag(path, rosbag::bagmode::Write);
    for (int round = 0; round < 3; ++round)
      for (std::size_t k = 0; k < damage.size(); ++k) {
        sensor_msgs::Image image;
        image.header.stamp = ros::Time(1.0 + round * 10 + k);
        image.encoding = "mono8";
        image.width = image.height = image.step = 4;
        image.data.assign(16, 7);
        damage[k](image);
        bag.write("/sun_sensor/image", image.header.stamp, image);
        digital_sun_sensor::SunAngles truth;
        truth.header.stamp = image.header.stamp;
        truth.valid = true;
        bag.write("/sun_sensor/truth", truth.header.stamp, truth);
      }
  }
  std::size_t read = 0;
  const dss::BagReadStats stats = dss::DatasetBagReader({path}).forEach([&](const dss::LabelledImage& item) {
    EXPECT_EQ(item.image.cols, 4);
    ++read;
    return true;
  });
  EXPECT_EQ(read, 3u);
  EXPECT_EQ(stats.pairs, 3u);
  EXPECT_EQ(stats.bad_images, 15u);
  EXPECT_NE(stats.first_bad_image.find("rgb8"), std::string::npos) << stats.first_bad_image;
  std::remove(path.c_str());
}

// An image payload's length fields are checked against its bytes before
// anything is allocated; sizes over the limits are refused by name.
TEST(Messages, ImagePayloadsAndFieldsAreBounded) {
  cv::Mat image(4, 6, CV_16UC1, cv::Scalar(300));
  const sensor_msgs::Image msg = dss::toImageMsg(image, std_msgs::Header());
  std::vector<std::uint8_t> bytes(ros::serialization::serializationLength(msg));
  ros::serialization::OStream out(bytes.data(), static_cast<std::uint32_t>(bytes.size()));
  ros::serialization::serialize(out, msg);
  const cv::Mat back = dss::imageFromMsg(dss::imageMsgFromBytes(bytes.data(), bytes.size()));
  EXPECT_EQ(cv::countNonZero(back != image), 0);

  auto errorOf = [](const std::function<void()>& f) -> std::string {
    try {
      f();
    } catch (const std::invalid_argument& e) {
      return e.what();
    }
    return "";
  };
  // The data length field (the last 4 + 48 bytes) claims 4 GB.
  std::vector<std::uint8_t> lying = bytes;
  const std::size_t length_at = bytes.size() - image.total() * 2 - 4;
  lying[length_at] = lying[length_at + 1] = lying[length_at + 2] = lying[length_at + 3] = 0xff;
  EXPECT_NE(errorOf([&] { dss::imageMsgFromBytes(lying.data(), lying.size()); }).find("over the limit"),
            std::string::npos);
  EXPECT_NE(errorOf([&] { dss::imageMsgFromBytes(bytes.data(), bytes.size() - 1); }).find("truncated in 'data'"),
            std::string::npos);
  sensor_msgs::Image wide = msg;
  wide.width = 100000;
  EXPECT_NE(errorOf([&] { dss::imageFromMsg(wide); }).find("over the limit of 8192 px"), std::string::npos);
}

TEST(Messages, StatusConstantsAreTheCoreCodes) {
  using digital_sun_sensor::SunAngles;
  const std::vector<std::string> message = {SunAngles::STATUS_NO_SUN,
                                            SunAngles::STATUS_SATURATED,
                                            SunAngles::STATUS_OUT_OF_DISTRIBUTION,
                                            SunAngles::STATUS_AMBIGUOUS_APERTURE,
                                            SunAngles::STATUS_OUTSIDE_FOV,
                                            SunAngles::STATUS_NOT_FINITE,
                                            SunAngles::STATUS_SUN_BEHIND_SENSOR,
                                            SunAngles::STATUS_BAD_IMAGE,
                                            SunAngles::STATUS_NO_MATCH,
                                            SunAngles::STATUS_INCONSISTENT_SPOTS,
                                            SunAngles::STATUS_SPOT_AT_EDGE,
                                            SunAngles::STATUS_ESTIMATOR_ERROR,
                                            SunAngles::STATUS_NO_ESTIMATOR,
                                            SunAngles::STATUS_MODEL_MISMATCH};
  const std::vector<std::string> core(std::begin(dss::status::kAll), std::end(dss::status::kAll));
  EXPECT_EQ(message, core);
  EXPECT_EQ(dss::status::statusCode("bad_image: 256x256"), SunAngles::STATUS_BAD_IMAGE);
  EXPECT_EQ(dss::status::statusCode(SunAngles::STATUS_NO_SUN), SunAngles::STATUS_NO_SUN);
}

// Bags recorded before SunAngles had its constants (another MD5 sum, the same
// fields) still give their truth; a recorded type with other fields does not.
TEST(Messages, TruthFromBagsOfTheOlderSunAnglesIsRead) {
  using digital_sun_sensor::SunAngles;
  const std::string definition = ros::message_traits::Definition<SunAngles>::value();
  std::string old_definition;  // the current text without the constant lines
  std::istringstream lines(definition);
  for (std::string line; std::getline(lines, line);)
    if (line.rfind("string STATUS_", 0) != 0) old_definition += line + "\n";
  for (const bool same_fields : {true, false}) {
    const std::string path = "/tmp/dss_test_old_truth_" + std::to_string(same_fields) + ".bag";
    {
      rosbag::Bag bag(path, rosbag::bagmode::Write);
      sensor_msgs::Image image;
      image.header.stamp = ros::Time(1.0);
      image.encoding = "mono8";
      image.width = image.height = image.step = 4;
      image.data.assign(16, 7);
      bag.write("/sun_sensor/image", image.header.stamp, image);
      SunAngles truth;
      truth.header.stamp = image.header.stamp;
      truth.alpha = 0.01;
      truth.beta = -0.02;
      truth.valid = true;
      truth.source = "truth";
      auto header = boost::make_shared<ros::M_string>();
      (*header)["type"] = "digital_sun_sensor/SunAngles";
      (*header)["md5sum"] = "0123456789abcdef0123456789abcdef";
      (*header)["message_definition"] = same_fields ? old_definition : "float64 gamma\n" + old_definition;
      bag.write("/sun_sensor/truth", truth.header.stamp, truth, header);
    }
    std::vector<dss::LabelledImage> read;
    const dss::BagReadStats stats = dss::DatasetBagReader({path}).forEach([&](const dss::LabelledImage& item) {
      read.push_back(item);
      return true;
    });
    if (same_fields) {
      ASSERT_EQ(read.size(), 1u);
      EXPECT_EQ(read[0].truth.alpha, 0.01);
      EXPECT_EQ(read[0].truth.beta, -0.02);
      EXPECT_TRUE(read[0].truth.valid);
      EXPECT_EQ(read[0].truth.source, "truth");
    } else {
      EXPECT_TRUE(read.empty());
      EXPECT_EQ(stats.unmatched_images, 1u);
    }
    std::remove(path.c_str());
  }
}
