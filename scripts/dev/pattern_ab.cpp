// pattern_ab CONFIG IMAGES BLOCKS A.so B.so: two builds of the pattern
// estimator timed on the same images of a drawn unit in alternating blocks
// (each block runs every image through A, then B, or B then A), in one
// process on one core: this machine's speed drifts by tens of percent from
// minute to minute, a block lasts a fraction of a second. Prints both
// builds' check sums and the median ratio of the blocks' thread CPU times.
#include <dlfcn.h>
#include <time.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <vector>

#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/sim/geometry.h"
#include "digital_sun_sensor/sim/renderer.h"

namespace {
double threadCpuMs() {
  timespec t;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return t.tv_sec * 1e3 + t.tv_nsec * 1e-6;
}
using Make = void* (*)(const dss::SensorConfig*);
using One = double (*)(void*, const cv::Mat*);
}  // namespace

int main(int argc, char** argv) {
  if (argc != 6) {
    std::fprintf(stderr, "usage: pattern_ab CONFIG IMAGES BLOCKS A.so B.so\n");
    return 2;
  }
  const dss::SensorConfig config = dss::loadSensorConfig(argv[1]);
  const int count = std::atoi(argv[2]), blocks = std::atoi(argv[3]);
  const dss::Renderer unit(dss::SensorInstance::draw(config, 7));
  dss::Rng rng(4249);
  std::vector<cv::Mat> images;
  for (int k = 0; k < count; ++k) {
    const double a = dss::degToRad(config.fov.alpha_max_deg) * rng.uniform(-1.0, 1.0);
    const double b = dss::degToRad(config.fov.beta_max_deg) * rng.uniform(-1.0, 1.0);
    images.push_back(unit.render(dss::sunVectorFromAngles(a, b), 1000 + k, nullptr));
  }
  void* estimator[2];
  One one[2];
  for (int v = 0; v < 2; ++v) {
    void* library = dlopen(argv[4 + v], RTLD_NOW | RTLD_LOCAL | RTLD_DEEPBIND);
    if (!library) {
      std::fprintf(stderr, "%s\n", dlerror());
      return 1;
    }
    estimator[v] = reinterpret_cast<Make>(dlsym(library, "make"))(&config);
    one[v] = reinterpret_cast<One>(dlsym(library, "one"));
  }
  double check[2] = {0.0, 0.0};
  for (int v = 0; v < 2; ++v)
    for (const cv::Mat& image : images) check[v] += one[v](estimator[v], &image);
  std::vector<double> ratio;
  double total_ms[2] = {0.0, 0.0};
  for (int block = 0; block < blocks; ++block) {
    double ms[2];
    for (int s = 0; s < 2; ++s) {
      const int v = (block + s) % 2;
      const double start = threadCpuMs();
      for (const cv::Mat& image : images) one[v](estimator[v], &image);
      ms[v] = (threadCpuMs() - start) / count;
    }
    ratio.push_back(ms[1] / ms[0]);
    total_ms[0] += ms[0], total_ms[1] += ms[1];
  }
  std::sort(ratio.begin(), ratio.end());
  std::printf(
      "{\"check_a\":%.12e,\"check_b\":%.12e,\"a_mean_ms\":%.3f,\"b_mean_ms\":%.3f,\"b_over_a_median\":%.4f,"
      "\"b_over_a_quartiles\":[%.4f,%.4f]}\n",
      check[0], check[1], total_ms[0] / blocks, total_ms[1] / blocks, ratio[ratio.size() / 2], ratio[ratio.size() / 4],
      ratio[3 * ratio.size() / 4]);
}
