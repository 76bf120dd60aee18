// Replays every committed fuzz input (the seeds each target starts from, and
// fuzz/regressions/<target>/: every input a fuzzer ever found a problem with)
// through its target. A target aborts, crashes or throws an exception other
// than its reader's own error on a finding, so passing means each input is
// accepted or refused by name.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#define DSS_FUZZ_TARGET(name) extern "C" int dss_fuzz_##name(const std::uint8_t*, std::size_t);
DSS_FUZZ_TARGET(sensor_config)
DSS_FUZZ_TARGET(calibration)
DSS_FUZZ_TARGET(metadata)
DSS_FUZZ_TARGET(model_file)
DSS_FUZZ_TARGET(checkpoint)
DSS_FUZZ_TARGET(bag_messages)
DSS_FUZZ_TARGET(image_msg)

namespace {

struct Target {
  const char* name;
  int (*entry)(const std::uint8_t*, std::size_t);
};

const Target kTargets[] = {{"sensor_config", dss_fuzz_sensor_config}, {"calibration", dss_fuzz_calibration},
                           {"metadata", dss_fuzz_metadata},           {"model_file", dss_fuzz_model_file},
                           {"checkpoint", dss_fuzz_checkpoint},       {"bag_messages", dss_fuzz_bag_messages},
                           {"image_msg", dss_fuzz_image_msg}};

class FuzzRegressions : public ::testing::TestWithParam<Target> {};

TEST_P(FuzzRegressions, EveryCommittedInputIsAcceptedOrRefusedByName) {
  namespace fs = std::filesystem;
  std::vector<fs::path> inputs;
  for (const char* kind : {"seeds", "regressions"}) {
    const fs::path dir = fs::path(DSS_SOURCE_DIR) / "fuzz" / kind / GetParam().name;
    if (!fs::is_directory(dir)) continue;
    for (const auto& entry : fs::directory_iterator(dir))
      if (entry.is_regular_file()) inputs.push_back(entry.path());
  }
  std::sort(inputs.begin(), inputs.end());
  ASSERT_FALSE(inputs.empty()) << "no seeds for fuzz target " << GetParam().name;
  for (const auto& path : inputs) {
    SCOPED_TRACE(path.string());
    std::ifstream in(path, std::ios::binary);
    const std::vector<char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    EXPECT_EQ(GetParam().entry(reinterpret_cast<const std::uint8_t*>(bytes.data()), bytes.size()), 0);
  }
}

INSTANTIATE_TEST_SUITE_P(Targets, FuzzRegressions, ::testing::ValuesIn(kTargets),
                         [](const ::testing::TestParamInfo<Target>& info) { return std::string(info.param.name); });

}  // namespace
