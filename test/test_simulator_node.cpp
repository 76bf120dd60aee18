// rostest: simulator_node publishes image + truth at the configured rate, with
// equal stamps, over a real master (simulator_node.test); under a small
// ~diffraction_cache_mb it keeps to it (simulator_cache_cap.test).
#include <diagnostic_msgs/DiagnosticArray.h>
#include <digital_sun_sensor/SpotCentres.h>
#include <digital_sun_sensor/SunAngles.h>
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <sensor_msgs/Image.h>

#include <map>
#include <mutex>
#include <string>

#include "digital_sun_sensor/common/units.h"

namespace {

std::mutex mutex;
std::vector<sensor_msgs::Image::ConstPtr> images;
std::map<double, digital_sun_sensor::SunAngles::ConstPtr> truths;

void onImage(const sensor_msgs::Image::ConstPtr& m) {
  std::lock_guard<std::mutex> lock(mutex);
  images.push_back(m);
}

void onTruth(const digital_sun_sensor::SunAngles::ConstPtr& m) {
  std::lock_guard<std::mutex> lock(mutex);
  truths[m->header.stamp.toSec()] = m;
}

TEST(SimulatorNode, PublishesImageAndTruthAtRateWithEqualStamps) {
  ros::NodeHandle nh, pnh("~");
  const double expected_hz = pnh.param("expected_rate_hz", 20.0);
  auto image_sub = nh.subscribe("/sun_sensor/image", 100, onImage);
  auto truth_sub = nh.subscribe("/sun_sensor/truth", 100, onTruth);
  // Wait for the first image (the node may still be starting), then measure.
  ros::Time deadline = ros::Time::now() + ros::Duration(80.0);
  while (ros::ok() && ros::Time::now() < deadline) {
    ros::spinOnce();
    std::lock_guard<std::mutex> lock(mutex);
    if (!images.empty()) break;
  }
  ASSERT_FALSE(images.empty()) << "no image on /sun_sensor/image within 80 s";
  {
    std::lock_guard<std::mutex> lock(mutex);
    images.clear();
    truths.clear();
  }
  const double window_s = 3.0;
  const ros::WallTime start = ros::WallTime::now();
  while (ros::ok() && (ros::WallTime::now() - start).toSec() < window_s) {
    ros::spinOnce();
    ros::WallDuration(0.002).sleep();
  }
  ros::WallDuration(0.3).sleep();
  ros::spinOnce();
  std::lock_guard<std::mutex> lock(mutex);
  const double rate = images.size() / window_s;
  EXPECT_NEAR(rate, expected_hz, 0.2 * expected_hz) << images.size() << " images in " << window_s << " s";
  ASSERT_GE(images.size(), 10u);
  int matched = 0;
  for (const auto& img : images) {
    EXPECT_EQ(img->width, 512u);
    EXPECT_EQ(img->height, 512u);
    EXPECT_EQ(img->encoding, "mono8");
    EXPECT_EQ(img->header.frame_id, "sun_sensor_link");
    auto it = truths.find(img->header.stamp.toSec());
    if (it == truths.end()) continue;
    ++matched;
    EXPECT_TRUE(it->second->valid);
    EXPECT_EQ(it->second->source, "truth");
    EXPECT_LE(std::abs(it->second->alpha), dss::degToRad(4.54) + 1e-9);
  }
  // Every image has its truth except possibly the first (its truth may have
  // been taken before the clear above, the image after it) and the last (its
  // truth may be in flight).
  EXPECT_GE(matched, static_cast<int>(images.size()) - 2);
}

// The simulator's status values by key, from its last /diagnostics message.
std::map<std::string, std::string> simulator_values;

void onDiagnostics(const diagnostic_msgs::DiagnosticArray::ConstPtr& m) {
  std::lock_guard<std::mutex> lock(mutex);
  for (const auto& status : m->status) {
    if (status.name.find("simulator") == std::string::npos) continue;
    std::map<std::string, std::string> values;
    for (const auto& kv : status.values) values[kv.key] = kv.value;
    if (values.count("diffraction cache nodes")) simulator_values = values;  // not its rate's status
  }
}

TEST(SimulatorNode, KeepsItsDiffractionCacheWithinItsCap) {
  ros::NodeHandle nh, pnh("~");
  const double cap_mb = pnh.param("cache_cap_mb", 2.0);
  auto image_sub = nh.subscribe("/sun_sensor/image", 100, onImage);
  auto diagnostics_sub = nh.subscribe("/diagnostics", 10, onDiagnostics);
  // Images go on (the spots the fixed attitude needs, computed again after
  // the warm-up dropped them), and the node reports the dropped spots.
  const ros::Time deadline = ros::Time::now() + ros::Duration(80.0);
  bool reported = false;
  while (ros::ok() && ros::Time::now() < deadline && !reported) {
    ros::spinOnce();
    ros::WallDuration(0.01).sleep();
    std::lock_guard<std::mutex> lock(mutex);
    reported = images.size() >= 5 && simulator_values.count("diffraction nodes dropped for memory") > 0;
  }
  std::lock_guard<std::mutex> lock(mutex);
  ASSERT_GE(images.size(), 5u) << "fewer than 5 images within 80 s";
  ASSERT_TRUE(reported) << "no simulator status with the diffraction cache on /diagnostics";
  EXPECT_GT(std::stoul(simulator_values["diffraction nodes dropped for memory"]), 0u);
  EXPECT_LE(std::stod(simulator_values["diffraction cache [MB]"]), cap_mb);
}

}  // namespace

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "test_simulator_node");
  return RUN_ALL_TESTS();
}
