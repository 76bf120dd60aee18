// rostest: calibration_node with thesis_ca's shipped model and a coarse sun
// sensor. Where the mask's pattern fits two places that are mirror images of
// each other (alpha about +-2.87 deg, 5.74 deg apart), the image alone is
// declined ambiguous_aperture; with a coarse direction near the truth it is
// answered there, and one about midway leaves it declined.
#include <digital_sun_sensor/SunAngles.h>
#include <geometry_msgs/Vector3Stamped.h>
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <sensor_msgs/Image.h>

#include <map>
#include <mutex>
#include <optional>

#include "digital_sun_sensor/common/estimate_status.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/ros/conversions.h"
#include "digital_sun_sensor/sim/geometry.h"
#include "digital_sun_sensor/sim/renderer.h"

namespace {

using digital_sun_sensor::SunAngles;

std::mutex mutex;
std::map<double, SunAngles::ConstPtr> answers;  // by stamp

TEST(CalibrationNode, CoarseSunDirectionChoosesBetweenMirrorImagePlaces) {
  ros::NodeHandle nh("/sun_sensor");
  ros::Publisher images = nh.advertise<sensor_msgs::Image>("image", 10);
  ros::Publisher coarse = nh.advertise<geometry_msgs::Vector3Stamped>("coarse_sun_vector", 10);
  ros::Subscriber sub = nh.subscribe<SunAngles>(
      "angles", 10, boost::function<void(const SunAngles::ConstPtr&)>([](const SunAngles::ConstPtr& m) {
        std::lock_guard<std::mutex> lock(mutex);
        answers[m->header.stamp.toSec()] = m;
      }));
  // The node loads the model and computes its design's spots first.
  const ros::WallTime connect_deadline = ros::WallTime::now() + ros::WallDuration(200.0);
  while (ros::ok() &&
         (images.getNumSubscribers() == 0 || coarse.getNumSubscribers() == 0 || sub.getNumPublishers() == 0) &&
         ros::WallTime::now() < connect_deadline)
    ros::WallDuration(0.1).sleep();
  ASSERT_GT(images.getNumSubscribers(), 0u);
  ASSERT_GT(coarse.getNumSubscribers(), 0u);

  const dss::SensorConfig config =
      dss::loadSensorConfig(std::string(DSS_SOURCE_DIR) + "/config/sensors/thesis_ca.yaml");
  const dss::Renderer renderer(dss::SensorInstance::nominalOf(config));
  const double alpha = dss::degToRad(2.87), beta = dss::degToRad(0.1);
  const cv::Mat image = renderer.render(dss::sunVectorFromAngles(alpha, beta), 2, nullptr);

  // The same image three times: no coarse direction, one near the truth, one about midway.
  const std::optional<double> coarse_alpha_deg[] = {std::nullopt, 4.0, 0.3};
  for (int i = 0; i < 3; ++i) {
    std_msgs::Header header;
    header.stamp = ros::Time(100.0 + i);
    header.frame_id = "sun_sensor_link";
    if (coarse_alpha_deg[i]) {
      coarse.publish(dss::toSunVectorMsg(dss::degToRad(*coarse_alpha_deg[i]), dss::degToRad(0.5), header));
      ros::WallDuration(0.05).sleep();  // the direction first
    }
    images.publish(dss::toImageMsg(image, header));
    // One at a time: the node's queue keeps the newest images only.
    const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(60.0);
    while (ros::ok() && ros::WallTime::now() < deadline) {
      {
        std::lock_guard<std::mutex> lock(mutex);
        if (answers.count(header.stamp.toSec())) break;
      }
      ros::WallDuration(0.05).sleep();
    }
  }
  std::lock_guard<std::mutex> lock(mutex);
  ASSERT_EQ(answers.size(), 3u);
  const SunAngles& alone = *answers.at(100.0);
  const SunAngles& near_truth = *answers.at(101.0);
  const SunAngles& midway = *answers.at(102.0);
  EXPECT_FALSE(alone.valid);
  EXPECT_EQ(dss::status::statusCode(alone.status), dss::status::kAmbiguousAperture) << alone.status;
  ASSERT_TRUE(near_truth.valid) << near_truth.status;
  EXPECT_NEAR(dss::radToDeg(near_truth.alpha), 2.87, 0.005);
  EXPECT_NEAR(dss::radToDeg(near_truth.beta), 0.1, 0.005);
  EXPECT_FALSE(midway.valid);
  EXPECT_EQ(dss::status::statusCode(midway.status), dss::status::kAmbiguousAperture) << midway.status;
}

}  // namespace

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "test_coarse_sun");
  ros::AsyncSpinner spinner(1);
  spinner.start();
  return RUN_ALL_TESTS();
}
