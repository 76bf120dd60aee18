// rostest: calibration_node recalibrates a drifted unit in flight. A
// geometric-head model of a drawn 5-aperture mask runs in calibration_node
// (in this process, over the real master); the unit's mask has since risen
// 20 um and moved 5 um. Images of it arrive with reference sun vectors (one
// in twenty grossly wrong); before the first refit the node must widen the
// sigma of its estimates to hold their error once the references show the
// drift, its error must fall once the refits start, it publishes the
// refitted geometry, and ~save_unit_model writes a unit model that loads.
#include <digital_sun_sensor/SunAngles.h>
#include <digital_sun_sensor/UnitGeometry.h>
#include <geometry_msgs/Vector3Stamped.h>
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <sensor_msgs/Image.h>
#include <std_srvs/Trigger.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <map>
#include <mutex>

#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/ros/calibration_node.h"
#include "digital_sun_sensor/ros/conversions.h"
#include "digital_sun_sensor/sim/geometry.h"
#include "digital_sun_sensor/sim/random_mask.h"
#include "digital_sun_sensor/sim/renderer.h"
#include "digital_sun_sensor/sim/sensor_instance.h"

namespace dss {
namespace {

using digital_sun_sensor::SunAngles;
using digital_sun_sensor::UnitGeometry;

std::mutex mutex;
std::map<double, SunAngles::ConstPtr> answers;  // by stamp
UnitGeometry::ConstPtr geometry_msg;

std::string tmp(const std::string& name) { return "/tmp/dss_recal_" + std::to_string(getpid()) + "_" + name; }

TEST(CalibrationNode, RecalibratesADriftedUnitFromReferences) {
  RandomMaskOptions mask;
  mask.apertures = 5;
  const SensorConfig design =
      drawRandomMask(loadSensorConfig(std::string(DSS_SOURCE_DIR) + "/config/sensors/thesis_sa.yaml",
                                      {"detector.width_px=640", "detector.height_px=512", "detector.pitch_um=2.2",
                                       "optics.psf_node_step_deg=3", "mask.height_mm=2.5", "fov.alpha_max_deg=6",
                                       "fov.beta_max_deg=6"}),
                     mask, 51)
          .config;
  // The model: the design's geometry, an untrained network (the solve alone).
  ArchSpec arch = archPreset("resnet10_w16", design.numSubFovClasses());
  arch.centroid_weighting = CentroidWeighting::kValue;
  HeadOptions head;
  head.head = "geometric";
  const std::string model_path = tmp("model.dssmodel"), unit_path = tmp("unit.dssmodel"),
                    config_path = tmp("sensor.yaml");
  {
    Model model = createModel(design, arch, 1, head);
    model.net->eval();
    saveModel(model, model_path);
  }
  {
    FILE* f = std::fopen(config_path.c_str(), "w");
    ASSERT_NE(f, nullptr);
    const std::string yaml = toYaml(design);
    std::fwrite(yaml.data(), 1, yaml.size(), f);
    std::fclose(f);
  }
  // The unit since drifted.
  SensorInstance unit = SensorInstance::nominalOf(design);
  unit.nominal = false;
  unit.mask_offset_um = Eigen::Vector3d(5.0, 0.0, 20.0);
  const Renderer renderer(unit);

  ros::NodeHandle nh("/sun_sensor"), pnh("/sun_sensor/calibration");
  pnh.setParam("sensor_config", config_path);
  pnh.setParam("model", model_path);
  pnh.setParam("calibration", "none");
  pnh.setParam("queue_size", 400);
  pnh.setParam("max_batch", 4);
  pnh.setParam("min_spot_px", 1);
  pnh.setParam("max_sigma_deg", 10.0);
  pnh.setParam("recalibration/enabled", true);
  pnh.setParam("recalibration/min_pairs", 30);
  pnh.setParam("recalibration/refit_every", 20);
  pnh.setParam("recalibration/window", 200);
  pnh.setParam("recalibration/output", unit_path);
  CalibrationNode node(nh, pnh);

  ros::Publisher images = nh.advertise<sensor_msgs::Image>("image", 400);
  ros::Publisher references = nh.advertise<geometry_msgs::Vector3Stamped>("reference_sun_vector", 400);
  ros::Subscriber angles = nh.subscribe<SunAngles>(
      "angles", 400, boost::function<void(const SunAngles::ConstPtr&)>([](const SunAngles::ConstPtr& m) {
        std::lock_guard<std::mutex> lock(mutex);
        answers[m->header.stamp.toSec()] = m;
      }));
  ros::Subscriber unit_geometry = nh.subscribe<UnitGeometry>(
      "unit_geometry", 1, boost::function<void(const UnitGeometry::ConstPtr&)>([](const UnitGeometry::ConstPtr& m) {
        std::lock_guard<std::mutex> lock(mutex);
        geometry_msg = m;
      }));
  const ros::WallTime connect_deadline = ros::WallTime::now() + ros::WallDuration(30.0);
  while (ros::ok() &&
         (images.getNumSubscribers() == 0 || references.getNumSubscribers() == 0 || angles.getNumPublishers() == 0) &&
         ros::WallTime::now() < connect_deadline)
    ros::WallDuration(0.05).sleep();
  ASSERT_GT(images.getNumSubscribers(), 0u);

  constexpr int kImages = 160;
  Rng rng(5);
  std::map<double, std::array<double, 2>> truth;
  for (int i = 0; i < kImages; ++i) {
    const double alpha = degToRad(rng.uniform(-5.0, 5.0)), beta = degToRad(rng.uniform(-5.0, 5.0));
    const cv::Mat image = renderer.render(sunVectorFromAngles(alpha, beta), 100 + i, nullptr);
    const ros::Time stamp(1000.0 + 0.1 * i);
    truth[stamp.toSec()] = {alpha, beta};
    std_msgs::Header header;
    header.stamp = stamp;
    header.frame_id = "sun_sensor_link";
    // One reference in twenty is grossly wrong (a star tracker outlier).
    references.publish(i % 20 == 7 ? toSunVectorMsg(alpha + degToRad(3.0), beta - degToRad(2.0), header)
                                   : toSunVectorMsg(alpha, beta, header));
    ros::WallDuration(0.002).sleep();  // the reference first
    images.publish(toImageMsg(image, header));
    ros::WallDuration(0.03).sleep();
  }
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(120.0);
  while (ros::ok() && ros::WallTime::now() < deadline) {
    {
      std::lock_guard<std::mutex> lock(mutex);
      if (answers.size() >= static_cast<std::size_t>(kImages)) break;
    }
    ros::WallDuration(0.05).sleep();
  }
  std::lock_guard<std::mutex> lock(mutex);
  ASSERT_EQ(answers.size(), static_cast<std::size_t>(kImages));
  // Mean error of the first 20 answers (before any refit) and of the last
  // 40; within 3 sigma: the first 8 answers (too few pairs to judge: their
  // own sigma) and answers 12-27 (the references show the drift; no refit
  // before 30 pairs).
  double early = 0.0, late = 0.0;
  int index = 0, late_valid = 0, own_held = 0, own_valid = 0, widened_held = 0, widened_valid = 0;
  for (const auto& [stamp, a] : answers) {
    const auto& t = truth.at(stamp);
    const double error = 0.5 * (std::abs(a->alpha - t[0]) + std::abs(a->beta - t[1]));
    const bool held = std::abs(a->alpha - t[0]) <= 3.0 * std::sqrt(a->covariance[0]) &&
                      std::abs(a->beta - t[1]) <= 3.0 * std::sqrt(a->covariance[3]);
    if (index < 20) early += radToDeg(error) / 20.0;
    if (index < 8 && a->valid) own_held += held, ++own_valid;
    if (index >= 12 && index < 28 && a->valid) widened_held += held, ++widened_valid;
    if (index >= kImages - 40 && a->valid) late += radToDeg(error), ++late_valid;
    ++index;
  }
  std::printf("within 3 sigma: %d of %d with their own sigma, %d of %d once the references judge\n", own_held,
              own_valid, widened_held, widened_valid);
  ASSERT_GT(own_valid, 4);
  ASSERT_GT(widened_valid, 12);
  EXPECT_LT(own_held, own_valid / 2);
  EXPECT_GE(widened_held, widened_valid - 1);
  ASSERT_GT(late_valid, 35);
  late /= late_valid;
  std::printf("in-flight recalibration: mean error %.5f deg before the refits, %.5f deg in the last 40 images\n", early,
              late);
  EXPECT_GT(early, 0.05);
  EXPECT_LT(late, 0.1 * early);
  ASSERT_NE(geometry_msg, nullptr);
  EXPECT_GT(geometry_msg->pairs, 100u);
  EXPECT_NEAR(geometry_msg->offset_x_um, 5.0, 1.0);
  EXPECT_GT(geometry_msg->standard_errors[0], 0.0);

  // The recalibrated unit is saved on request and loads for its design.
  std_srvs::Trigger save;
  ASSERT_TRUE(ros::service::call("/sun_sensor/calibration/save_unit_model", save));
  EXPECT_TRUE(save.response.success) << save.response.message;
  const Model saved = loadModel(unit_path, &design);
  EXPECT_NEAR(saved.net->geometry()->maskGeometry().offset_x_um, geometry_msg->offset_x_um, 1e-9);
  EXPECT_NE(saved.meta.unit_yaml.find("in flight"), std::string::npos) << saved.meta.unit_yaml;
  for (const auto& f : {model_path, unit_path, config_path}) std::remove(f.c_str());
}

}  // namespace
}  // namespace dss

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "test_recalibration");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
