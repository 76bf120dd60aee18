// rostest: trainer_node over a real master. It trains on a small generated
// bag and writes a model that loads; SIGINT checkpoints and a relaunch with
// ~resume finishes the job; a missing bag fails with a message naming it.
#include <digital_sun_sensor/TrainingProgress.h>
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <fstream>
#include <mutex>

#include "digital_sun_sensor/model/sscnn_estimator.h"

namespace {

const std::string kDir = "/tmp/dss_trainer_node_test";
const std::string kNs = "/trainer_test/trainer";

std::mutex mutex;
std::vector<digital_sun_sensor::TrainingProgress> received;

void onProgress(const digital_sun_sensor::TrainingProgress::ConstPtr& m) {
  std::lock_guard<std::mutex> lock(mutex);
  received.push_back(*m);
}

// The last message, or an empty one.
digital_sun_sensor::TrainingProgress lastProgress() {
  std::lock_guard<std::mutex> lock(mutex);
  return received.empty() ? digital_sun_sensor::TrainingProgress() : received.back();
}

pid_t launchTrainer() {
  {
    std::lock_guard<std::mutex> lock(mutex);
    received.clear();
  }
  const pid_t pid = fork();
  if (pid == 0) {
    execl(DSS_TRAINER_NODE, DSS_TRAINER_NODE, "__name:=trainer", "__ns:=/trainer_test", static_cast<char*>(nullptr));
    _exit(127);
  }
  return pid;
}

// Exit code of the node (waits up to timeout_s, spinning meanwhile), -1 on timeout.
int waitExit(pid_t pid, double timeout_s) {
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(timeout_s);
  while (ros::WallTime::now() < deadline) {
    int status = 0;
    if (waitpid(pid, &status, WNOHANG) == pid) return WIFEXITED(status) ? WEXITSTATUS(status) : -2;
    ros::WallDuration(0.05).sleep();
  }
  kill(pid, SIGKILL);
  waitpid(pid, nullptr, 0);
  return -1;
}

void setTrainerParams(const std::string& bags, int epochs, bool resume) {
  ros::NodeHandle pnh(kNs);
  pnh.setParam("bags", bags);
  pnh.setParam("output", kDir + "/model.dssm");
  pnh.setParam("arch", "resnet10_w16");
  pnh.setParam("epochs", epochs);
  pnh.setParam("batch_size", 16);
  pnh.setParam("resume", resume);
  pnh.setParam("validation_fraction", 0.2);
}

class TrainerNode : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    ASSERT_EQ(std::system(("rm -rf " + kDir + " && mkdir -p " + kDir).c_str()), 0);
    const std::string cmd = std::string(DSS_BINARY) + " generate --sensor " + DSS_SOURCE_DIR +
                            "/config/sensors/thesis_sa.yaml --set optics.psf_node_step_deg=3 --count 160 --seed 4 "
                            "--out " + kDir + "/data.bag 2>/dev/null";
    ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
  }
};

TEST_F(TrainerNode, TrainsAndWritesAModelThatLoads) {
  ros::NodeHandle nh;
  auto sub = nh.subscribe(kNs + "/progress", 100, onProgress);
  setTrainerParams(kDir + "/data.bag", 3, false);
  const pid_t pid = launchTrainer();
  EXPECT_EQ(waitExit(pid, 120), 0);
  ros::WallDuration(0.3).sleep();
  const auto last = lastProgress();
  EXPECT_EQ(last.state, "finished");
  EXPECT_EQ(last.epoch, 3);
  EXPECT_EQ(last.model, kDir + "/model.dssm");
  EXPECT_GT(last.best_epoch, 0);
  EXPECT_GT(last.val_alpha_mean_deg, 0.0);
  EXPECT_LT(last.val_alpha_mean_deg, 0.1);
  bool saw_epoch_end = false;
  {
    std::lock_guard<std::mutex> lock(mutex);
    for (const auto& m : received) saw_epoch_end |= m.epoch_end;
  }
  EXPECT_TRUE(saw_epoch_end);
  EXPECT_NO_THROW(dss::SscnnEstimator(kDir + "/model.dssm"));
}

TEST_F(TrainerNode, SigintCheckpointsAndResumeFinishes) {
  ros::NodeHandle nh;
  auto sub = nh.subscribe(kNs + "/progress", 100, onProgress);
  std::remove((kDir + "/model.dssm.ckpt").c_str());
  setTrainerParams(kDir + "/data.bag", 4, false);
  const pid_t pid = launchTrainer();
  // Interrupt once training has started.
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(60);
  while (lastProgress().state != "training" && ros::WallTime::now() < deadline) ros::WallDuration(0.01).sleep();
  ASSERT_EQ(lastProgress().state, "training");
  kill(pid, SIGINT);
  EXPECT_EQ(waitExit(pid, 60), 3);
  ros::WallDuration(0.3).sleep();
  EXPECT_EQ(lastProgress().state, "interrupted");
  EXPECT_TRUE(std::ifstream(kDir + "/model.dssm.ckpt").good());

  setTrainerParams(kDir + "/data.bag", 4, true);
  EXPECT_EQ(waitExit(launchTrainer(), 120), 0);
  ros::WallDuration(0.3).sleep();
  EXPECT_EQ(lastProgress().state, "finished");
  EXPECT_EQ(lastProgress().epoch, 4);
}

TEST_F(TrainerNode, MissingBagFailsWithItsName) {
  ros::NodeHandle nh;
  auto sub = nh.subscribe(kNs + "/progress", 100, onProgress);
  setTrainerParams(kDir + "/no_such.bag", 1, false);
  EXPECT_EQ(waitExit(launchTrainer(), 60), 1);
  ros::WallDuration(0.3).sleep();
  EXPECT_EQ(lastProgress().state, "failed");
  EXPECT_NE(lastProgress().detail.find("no_such.bag"), std::string::npos) << lastProgress().detail;
}

}  // namespace

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "test_trainer_node");
  ros::AsyncSpinner spinner(1);
  spinner.start();
  return RUN_ALL_TESTS();
}
