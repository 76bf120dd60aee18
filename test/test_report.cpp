// dss report's core on a small run: every plot is a valid PNG that the HTML
// shows, and summary.json carries every figure.
#include <gtest/gtest.h>

#include <filesystem>
#include <opencv2/imgcodecs.hpp>

#include "digital_sun_sensor/baseline/calibration.h"
#include "digital_sun_sensor/baseline/centroid_estimator.h"
#include "digital_sun_sensor/common/file_io.h"
#include "digital_sun_sensor/estimate/screened_estimator.h"
#include "digital_sun_sensor/eval/report.h"
#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/model/sscnn_estimator.h"
#include "digital_sun_sensor/sparse/threads.h"

namespace dss {
namespace {

TEST(Report, SmallReportHasEveryPlotAndFigure) {
  // Coarse diffraction nodes keep the rendering short; the model does not depend on them.
  const SensorConfig sensor =
      loadSensorConfig(std::string(DSS_SOURCE_DIR) + "/config/sensors/thesis_sa.yaml", {"optics.psf_node_step_deg=3"});
  sparse::configureThreads(1, 1);
  ScreenedEstimator sscnn(
      std::make_unique<SscnnEstimator>(std::string(DSS_SOURCE_DIR) + "/models/thesis_sa.dssmodel", &sensor),
      ScreenOptions{});
  CentroidEstimator baseline(loadCalibration(std::string(DSS_SOURCE_DIR) + "/models/thesis_sa.calib.yaml"));
  ReportOptions options;
  options.out_dir = ::testing::TempDir() + "dss_report_test";
  std::filesystem::remove_all(options.out_dir);
  options.test_images = 40;
  options.sweep_images = 4;
  options.sweep_sensors = 1;
  options.command = "test";
  // The published protocol with the shipped model trained on it and its baseline.
  const std::string published_model = std::string(DSS_SOURCE_DIR) + "/models/thesis_sa_published.dssmodel";
  PublishedProtocolRun published;
  published.sensor = parseSensorConfig(loadModel(published_model).meta.sensor_yaml, published_model);
  SscnnEstimator published_sscnn(published_model, &published.sensor);
  CentroidEstimator published_baseline(
      loadCalibration(std::string(DSS_SOURCE_DIR) + "/models/thesis_sa_published.calib.yaml"));
  published.sscnn = &published_sscnn;
  published.baseline = &published_baseline;
  options.published_images = 20;
  const std::string summary = writeReport(sensor, sscnn, &baseline, options, {}, &published);
  EXPECT_EQ(readFile(options.out_dir + "/summary.json", 1 << 20), summary + "\n");

  const std::string html = readFile(options.out_dir + "/index.html", 16 << 20);
  std::vector<std::string> plots;
  for (std::size_t at = summary.find(".png\""); at != std::string::npos; at = summary.find(".png\"", at + 1)) {
    const std::size_t start = summary.rfind('"', at) + 1;
    plots.push_back(summary.substr(start, at + 4 - start));
  }
  EXPECT_EQ(plots.size(), 4u + 3u + 10u);  // 4 maps, histogram, error vs truth, reliability, 10 sweeps
  for (const auto& p : plots) {
    const std::string bytes = readFile(options.out_dir + "/" + p, 16 << 20);
    ASSERT_GT(bytes.size(), 8u) << p;
    EXPECT_EQ(bytes.substr(0, 8), std::string("\x89PNG\r\n\x1a\n", 8)) << p;
    const cv::Mat image = cv::imread(options.out_dir + "/" + p);
    EXPECT_FALSE(image.empty()) << p << " does not decode";
    EXPECT_NE(html.find("src=\"" + p + "\""), std::string::npos) << p << " is not in index.html";
  }
  for (const char* key : {"\"sscnn\": {", "\"baseline\": {", "\"alpha_mean_deg\"", "\"alpha_within_1sigma\"",
                          "\"beta_within_2sigma\"", "\"sscnn_false_alarm_rate\"", "\"reliability_sscnn_alpha\"",
                          "\"reliability_baseline_beta\"", "\"robustness\": [", "\"term\": \"shot_noise\"",
                          "\"term\": \"hot_pixels\"", "\"term\": \"debris\"", "\"term\": \"as_built\"",
                          "\"sscnn_valid_rate\"", "\"baseline_mean_deg\"", "\"published_sscnn\"", "\"provenance\""})
    EXPECT_NE(summary.find(key), std::string::npos) << key;
  // The published-protocol model on grid positions it never saw: about 0.001 deg per axis.
  const std::size_t protocol = summary.find("\"published_protocol\": {");
  ASSERT_NE(protocol, std::string::npos);
  for (const char* key : {"\"sscnn\": {\"estimator\"", "\"baseline\": {\"estimator\""})
    EXPECT_NE(summary.find(key, protocol), std::string::npos) << key;
  const std::size_t mean_at = summary.find("\"alpha_mean_deg\": ", protocol);
  ASSERT_NE(mean_at, std::string::npos);
  EXPECT_LT(std::stod(summary.substr(mean_at + 18)), 0.005);
  EXPECT_NE(html.find("published protocol"), std::string::npos);
  // Figures that must exist (the Cramer-Rao keys are null: the report does not compute the bound).
  for (const char* missing :
       {"\"alpha_mean_deg\": null", "\"alpha_within_1sigma\": null", "\"sscnn_false_alarm_rate\": null"})
    EXPECT_EQ(summary.find(missing), std::string::npos) << missing;
  std::filesystem::remove_all(options.out_dir);
}

}  // namespace
}  // namespace dss
