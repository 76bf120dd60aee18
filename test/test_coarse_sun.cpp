// rostests: calibration_node with thesis_ca's shipped model. Where the
// mask's pattern fits two places that are mirror images of each other (alpha
// about +-2.87 deg, 5.74 deg apart), the image alone is declined
// ambiguous_aperture. coarse_sun.test: with a coarse sun sensor's direction
// near the truth it is answered there, and one about midway leaves it
// declined. tracking.test: the node's own answer a moment before chooses,
// one older than ~tracking/max_age_s does not, and an answer far from the
// last one is counted in diagnostics.
#include <diagnostic_msgs/DiagnosticArray.h>
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
diagnostic_msgs::DiagnosticStatus estimator_status;

// thesis_ca's nominal design seen from (alpha, beta) [deg].
cv::Mat thesisCaImage(double alpha_deg, double beta_deg) {
  static const dss::SensorConfig config =
      dss::loadSensorConfig(std::string(DSS_SOURCE_DIR) + "/config/sensors/thesis_ca.yaml");
  static const dss::Renderer renderer(dss::SensorInstance::nominalOf(config));
  return renderer.render(dss::sunVectorFromAngles(dss::degToRad(alpha_deg), dss::degToRad(beta_deg)), 2, nullptr);
}

// Waits for the node (it loads the model and computes its design's spots
// first), then publishes images one at a time, each once the last was
// answered (the node's queue keeps the newest images only).
class ThesisCaNode {
 public:
  ThesisCaNode() : nh_("/sun_sensor") {
    images_ = nh_.advertise<sensor_msgs::Image>("image", 10);
    answers_ = nh_.subscribe<SunAngles>(
        "angles", 10, boost::function<void(const SunAngles::ConstPtr&)>([](const SunAngles::ConstPtr& m) {
          std::lock_guard<std::mutex> lock(mutex);
          answers[m->header.stamp.toSec()] = m;
        }));
    diagnostics_ = nh_.subscribe<diagnostic_msgs::DiagnosticArray>(
        "/diagnostics", 10,
        boost::function<void(const diagnostic_msgs::DiagnosticArray::ConstPtr&)>(
            [](const diagnostic_msgs::DiagnosticArray::ConstPtr& m) {
              std::lock_guard<std::mutex> lock(mutex);
              for (const auto& s : m->status)
                if (s.name.find("estimator") != std::string::npos) estimator_status = s;
            }));
  }
  // Whether the node and `also` (if given) are connected within 200 s.
  bool connected(const ros::Publisher* also = nullptr) {
    const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(200.0);
    while (ros::ok() && ros::WallTime::now() < deadline) {
      if (images_.getNumSubscribers() > 0 && answers_.getNumPublishers() > 0 &&
          (!also || also->getNumSubscribers() > 0))
        return true;
      ros::WallDuration(0.1).sleep();
    }
    return false;
  }
  // The answer to `image` stamped `stamp_s` (null after 60 s).
  SunAngles::ConstPtr answer(const cv::Mat& image, double stamp_s) {
    std_msgs::Header header;
    header.stamp = ros::Time(stamp_s);
    header.frame_id = "sun_sensor_link";
    images_.publish(dss::toImageMsg(image, header));
    const double key = header.stamp.toSec();  // as the answer's stamp converts
    const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(60.0);
    while (ros::ok() && ros::WallTime::now() < deadline) {
      {
        std::lock_guard<std::mutex> lock(mutex);
        if (answers.count(key)) return answers.at(key);
      }
      ros::WallDuration(0.05).sleep();
    }
    return nullptr;
  }
  ros::NodeHandle& handle() { return nh_; }

 private:
  ros::NodeHandle nh_;
  ros::Publisher images_;
  ros::Subscriber answers_, diagnostics_;
};

std::string diagnosticValue(const diagnostic_msgs::DiagnosticStatus& status, const std::string& key) {
  for (const auto& kv : status.values)
    if (kv.key == key) return kv.value;
  return "";
}

TEST(CalibrationNode, CoarseSunDirectionChoosesBetweenMirrorImagePlaces) {
  ThesisCaNode node;
  ros::Publisher coarse = node.handle().advertise<geometry_msgs::Vector3Stamped>("coarse_sun_vector", 10);
  ASSERT_TRUE(node.connected(&coarse));
  const cv::Mat image = thesisCaImage(2.87, 0.1);

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
    node.answer(image, header.stamp.toSec());
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

// ~tracking/max_rate_deg_s 10, max_age_s 1 (tracking.test).
TEST(CalibrationNode, ItsOwnLastAnswerChoosesBetweenMirrorImagePlaces) {
  ThesisCaNode node;
  ASSERT_TRUE(node.connected());
  const cv::Mat near_band = thesisCaImage(2.0, 0.1), at_alias = thesisCaImage(2.87, 0.1);
  const cv::Mat other_side = thesisCaImage(-2.0, 0.1);

  // Three answers near the band, each within the bound of the one before.
  ASSERT_TRUE(node.answer(near_band, 199.9));
  ASSERT_TRUE(node.answer(near_band, 199.95));
  const auto first = node.answer(near_band, 200.0);
  ASSERT_TRUE(first);
  ASSERT_TRUE(first->valid) << "outside the alias band the image alone decides: " << first->status;
  // 0.1 s later the sun lies within 1 deg of that answer: 4 deg nearer one place than the other.
  const auto tracked = node.answer(at_alias, 200.1);
  ASSERT_TRUE(tracked);
  ASSERT_TRUE(tracked->valid) << tracked->status;
  EXPECT_NEAR(dss::radToDeg(tracked->alpha), 2.87, 0.005);
  EXPECT_NEAR(dss::radToDeg(tracked->beta), 0.1, 0.005);
  // 2 s after the last answer (beyond max_age_s): the image alone, declined.
  const auto stale = node.answer(at_alias, 202.1);
  ASSERT_TRUE(stale);
  EXPECT_FALSE(stale->valid);
  EXPECT_EQ(dss::status::statusCode(stale->status), dss::status::kAmbiguousAperture) << stale->status;
  // An answer the image decides alone 4 deg from one 0.05 s before (a 10 deg/s
  // bound allows 0.5 deg): counted, and the alias image right after is
  // declined, not chosen from there (the place 0.87 deg off it).
  ASSERT_TRUE(node.answer(near_band, 203.0));
  const auto jumped = node.answer(other_side, 203.05);
  ASSERT_TRUE(jumped);
  EXPECT_TRUE(jumped->valid) << jumped->status;
  EXPECT_NEAR(dss::radToDeg(jumped->alpha), -2.0, 0.005) << "the image's own answer, not the prior's";
  const auto after_jump = node.answer(at_alias, 203.1);
  ASSERT_TRUE(after_jump);
  EXPECT_FALSE(after_jump->valid) << "answered at alpha " << dss::radToDeg(after_jump->alpha);

  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(5.0);
  while (ros::ok() && ros::WallTime::now() < deadline) {
    {
      std::lock_guard<std::mutex> lock(mutex);
      if (diagnosticValue(estimator_status, "answers contradicting the tracking prior") == "1") break;
    }
    ros::WallDuration(0.05).sleep();
  }
  std::lock_guard<std::mutex> lock(mutex);
  EXPECT_EQ(diagnosticValue(estimator_status, "answers contradicting the tracking prior"), "1");
  EXPECT_EQ(diagnosticValue(estimator_status, "images with the tracking prior"), "1")
      << "the one at 200.1 (a first answer gives none; the one at 200.1 was too old for 202.1 and 203.0)";
}

}  // namespace

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "test_coarse_sun");
  ros::AsyncSpinner spinner(1);
  spinner.start();
  return RUN_ALL_TESTS();
}
