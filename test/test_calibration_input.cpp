// rostest: calibration_node survives malformed images. Each case gets
// valid = false with its reason (or is counted), the node stays up and still
// estimates a good image afterwards, and a node with neither model nor
// calibration answers every image with "no_estimator".
#include <diagnostic_msgs/DiagnosticArray.h>
#include <digital_sun_sensor/SunAngles.h>
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <sensor_msgs/Image.h>

#include <cmath>
#include <mutex>

#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/sim/geometry.h"
#include "digital_sun_sensor/sim/renderer.h"

using dss::kRadPerDeg;

namespace {

using digital_sun_sensor::SunAngles;

std::mutex mutex;
std::vector<SunAngles::ConstPtr> answers;
std::map<std::string, diagnostic_msgs::DiagnosticStatus> statuses;  // by node name prefix

sensor_msgs::ImagePtr makeImage(const std::string& encoding, int width, int height, std::uint8_t fill) {
  auto msg = boost::make_shared<sensor_msgs::Image>();
  msg->encoding = encoding;
  msg->width = width;
  msg->height = height;
  const int channels = encoding == "rgb8" ? 3 : 1;
  msg->step = width * channels;
  msg->data.assign(static_cast<std::size_t>(msg->step) * height, fill);
  msg->header.frame_id = "sun_sensor_link";
  return msg;
}

sensor_msgs::ImagePtr renderedImage(double alpha_deg, double beta_deg) {
  const dss::SensorConfig config =
      dss::loadSensorConfig(std::string(DSS_SOURCE_DIR) + "/config/sensors/thesis_sa.yaml");
  const dss::Renderer renderer(dss::SensorInstance::draw(config, 1));
  dss::ImageTruth truth;
  const cv::Mat image =
      renderer.render(dss::sunVectorFromAngles(alpha_deg * kRadPerDeg, beta_deg * kRadPerDeg), 3, &truth);
  auto msg = makeImage("mono8", image.cols, image.rows, 0);
  for (int r = 0; r < image.rows; ++r) std::memcpy(&msg->data[r * msg->step], image.ptr(r), image.cols);
  return msg;
}

void onAnswer(const SunAngles::ConstPtr& m);

class Client {
 public:
  explicit Client(const std::string& ns) : nh_(ns) {
    pub_ = nh_.advertise<sensor_msgs::Image>("image", 10);
    sub_ = nh_.subscribe("angles", 10, onAnswer);
  }
  bool connected() const { return pub_.getNumSubscribers() > 0 && sub_.getNumPublishers() > 0; }
  // Publishes one image and waits for its answer (matched by stamp).
  SunAngles::ConstPtr ask(sensor_msgs::ImagePtr msg) {
    msg->header.stamp = ros::Time::now();
    pub_.publish(msg);
    const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(20.0);
    while (ros::ok() && ros::WallTime::now() < deadline) {
      ros::spinOnce();
      std::lock_guard<std::mutex> lock(mutex);
      for (const auto& a : answers)
        if (a->header.stamp == msg->header.stamp) return a;
      ros::WallDuration(0.005).sleep();
    }
    return nullptr;
  }

 private:
  ros::NodeHandle nh_;
  ros::Publisher pub_;
  ros::Subscriber sub_;
};

void waitFor(const Client& client) {
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(60.0);
  while (ros::ok() && !client.connected() && ros::WallTime::now() < deadline) ros::WallDuration(0.05).sleep();
  ASSERT_TRUE(client.connected()) << "calibration_node did not connect within 60 s";
  ros::WallDuration(0.3).sleep();
}

void onDiagnostics(const diagnostic_msgs::DiagnosticArray::ConstPtr& m) {
  std::lock_guard<std::mutex> lock(mutex);
  for (const auto& s : m->status) statuses[s.name.substr(0, s.name.find(':'))] = s;
}

ros::Subscriber subscribeDiagnostics(ros::NodeHandle& nh) { return nh.subscribe("/diagnostics", 10, onDiagnostics); }

void onAnswer(const SunAngles::ConstPtr& m) {
  std::lock_guard<std::mutex> lock(mutex);
  answers.push_back(m);
}

// The latest status of `node` after a few diagnostics periods.
diagnostic_msgs::DiagnosticStatus latestStatus(const std::string& node) {
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(3.0);
  while (ros::ok() && ros::WallTime::now() < deadline) {
    ros::spinOnce();
    ros::WallDuration(0.05).sleep();
  }
  std::lock_guard<std::mutex> lock(mutex);
  return statuses[node];
}

std::string value(const diagnostic_msgs::DiagnosticStatus& status, const std::string& key) {
  for (const auto& kv : status.values)
    if (kv.key == key) return kv.value;
  return "";
}

TEST(CalibrationNode, SurvivesMalformedImages) {
  ros::NodeHandle nh;
  ros::Subscriber diagnostics = subscribeDiagnostics(nh);
  Client client("/sun_sensor");
  waitFor(client);

  struct Case {
    const char* what;
    sensor_msgs::ImagePtr image;
    std::string status_prefix;
  };
  auto short_buffer = makeImage("mono8", 512, 512, 0);
  short_buffer->data.resize(1000);
  const Case cases[] = {
      {"wrong encoding", makeImage("rgb8", 512, 512, 0), digital_sun_sensor::SunAngles::STATUS_BAD_IMAGE},
      {"size unlike the sensor", makeImage("mono8", 256, 256, 0), digital_sun_sensor::SunAngles::STATUS_BAD_IMAGE},
      {"short data buffer", short_buffer, digital_sun_sensor::SunAngles::STATUS_BAD_IMAGE},
      {"all zero", makeImage("mono8", 512, 512, 0), digital_sun_sensor::SunAngles::STATUS_NO_SUN},
      {"all saturated", makeImage("mono8", 512, 512, 255), digital_sun_sensor::SunAngles::STATUS_SATURATED},
  };
  for (const Case& c : cases) {
    const SunAngles::ConstPtr answer = client.ask(c.image);
    ASSERT_TRUE(answer) << c.what << ": no answer (did the node die?)";
    EXPECT_FALSE(answer->valid) << c.what;
    EXPECT_EQ(answer->status.rfind(c.status_prefix, 0), 0u) << c.what << ": status '" << answer->status << "'";
    EXPECT_EQ(answer->source, "sscnn");
  }
  // Still up, and still right on a real image.
  const SunAngles::ConstPtr good = client.ask(renderedImage(1.0, -0.5));
  ASSERT_TRUE(good) << "no answer to a good image after the malformed ones";
  EXPECT_TRUE(good->valid) << good->status;
  EXPECT_NEAR(good->alpha, 1.0 * kRadPerDeg, 0.01 * kRadPerDeg);
  EXPECT_NEAR(good->beta, -0.5 * kRadPerDeg, 0.01 * kRadPerDeg);
  const auto status = latestStatus("sun_sensor/calibration");
  EXPECT_EQ(value(status, "bad images"), "3");
  EXPECT_EQ(value(status, "images processed"), "6");
}

TEST(CalibrationNode, WithoutModelOrCalibrationAnswersInvalid) {
  ros::NodeHandle nh;
  ros::Subscriber diagnostics = subscribeDiagnostics(nh);
  Client client("/none/sun_sensor");
  waitFor(client);
  const SunAngles::ConstPtr answer = client.ask(renderedImage(0.5, 0.5));
  ASSERT_TRUE(answer);
  EXPECT_FALSE(answer->valid);
  EXPECT_EQ(answer->status, digital_sun_sensor::SunAngles::STATUS_NO_ESTIMATOR);
  EXPECT_EQ(answer->source, "none");
  const auto status = latestStatus("none/sun_sensor/calibration");
  EXPECT_EQ(status.level, diagnostic_msgs::DiagnosticStatus::ERROR) << status.message;
  EXPECT_NE(status.message.find("no estimator"), std::string::npos) << status.message;
}

TEST(CalibrationNode, InferenceSymmetryNoneEstimatesTheImageAlone) {
  ros::NodeHandle nh;
  ros::Subscriber diagnostics = subscribeDiagnostics(nh);
  Client averaged("/sun_sensor"), alone("/alone/sun_sensor");
  waitFor(averaged);
  waitFor(alone);
  const SunAngles::ConstPtr a = averaged.ask(renderedImage(-2.0, 1.5));
  const SunAngles::ConstPtr b = alone.ask(renderedImage(-2.0, 1.5));
  ASSERT_TRUE(a && b);
  ASSERT_TRUE(a->valid && b->valid) << a->status << " / " << b->status;
  // Both right; not the same number, since one is the mean over 8 mirror images.
  EXPECT_NEAR(b->alpha, -2.0 * kRadPerDeg, 0.01 * kRadPerDeg);
  EXPECT_NEAR(b->beta, 1.5 * kRadPerDeg, 0.01 * kRadPerDeg);
  EXPECT_TRUE(a->alpha != b->alpha || a->beta != b->beta);
  EXPECT_EQ(value(latestStatus("sun_sensor/calibration"), "inference symmetry"), "dihedral");
  EXPECT_EQ(value(latestStatus("alone/sun_sensor/calibration"), "inference symmetry"), "none");
}

}  // namespace

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "test_calibration_input");
  return RUN_ALL_TESTS();
}
