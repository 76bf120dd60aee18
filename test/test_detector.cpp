// Detector model: photon transfer (mean and variance of shot + read noise),
// saturation, quantisation, dark current temperature law, thresholding.
#include "digital_sun_sensor/sim/readout.h"
#include "digital_sun_sensor/sim/renderer.h"

#include <gtest/gtest.h>

#include <cmath>

namespace dss {
namespace {

SensorConfig detectorConfig(int bit_depth, double read_noise_e) {
  SensorConfig c = loadSensorConfig(std::string(DSS_SOURCE_DIR) + "/config/sensors/thesis_sa.yaml");
  c.noise.bit_depth = bit_depth;
  c.noise.read_noise_e = read_noise_e;
  c.noise.dark_current_e_per_s = 0.0;
  c.noise.dsnu_fraction = 0.0;
  c.noise.prnu_fraction = 0.0;
  c.threshold.enabled = false;
  return c;
}

struct Moments {
  double mean = 0, var = 0;
};

Moments moments(const cv::Mat& image) {
  cv::Mat f;
  image.convertTo(f, CV_64F);
  cv::Scalar mean, stddev;
  cv::meanStdDev(f, mean, stddev);
  return {mean[0], stddev[0] * stddev[0]};
}

TEST(Detector, PhotonTransferMeanAndVariance) {
  // 12-bit ADC, 0.5 DN/e: DN mean = K mu, variance = K^2 (mu + sigma_r^2) + 1/12.
  const SensorConfig c = detectorConfig(12, 3.0);
  const Renderer r(SensorInstance::nominalOf(c));
  const double gain = 4095.0 / 8180.0;
  Rng rng(7);
  for (double mu : {20.0, 300.0, 2000.0, 6000.0}) {
    const cv::Mat signal(512, 512, CV_32F, cv::Scalar(mu));
    const Moments m = moments(r.detect(signal, 1e-3, rng));
    EXPECT_NEAR(m.mean, gain * mu, 0.002 * gain * mu + 0.02) << "mu " << mu;
    const double var = gain * gain * (mu + 9.0) + 1.0 / 12.0;
    EXPECT_NEAR(m.var / var, 1.0, 0.02) << "mu " << mu;
  }
}

TEST(Detector, ReadNoiseOnlyAtZeroSignal) {
  // Wide read-noise distribution at n = 0: exercises the exception sampling.
  SensorConfig c = detectorConfig(16, 3.0);
  c.noise.black_level_dn = 200.0;
  const Renderer r(SensorInstance::nominalOf(c));
  const double gain = 65535.0 / 8180.0;
  Rng rng(11);
  const Moments m = moments(r.detect(cv::Mat(512, 512, CV_32F, cv::Scalar(0)), 1e-3, rng));
  EXPECT_NEAR(m.mean, 200.0, 0.2);
  EXPECT_NEAR(m.var / (gain * gain * 9.0 + 1.0 / 12.0), 1.0, 0.02);
}

TEST(Detector, RareReadNoiseExceptionsAtReferenceGain) {
  // 8-bit, 32 e/DN, sigma 3 e: a pixel with no electrons reads 1 DN only if the
  // read noise exceeds 16 e (5.33 sigma): p = 4.8e-8. Check the table.
  const ReadoutTable t(detectorConfig(8, 3.0).noise);
  EXPECT_EQ(t.zeroMode(), 0);
  const double expected = 0.5 * std::erfc((0.5 * 8180.0 / 255.0 / 3.0) / std::sqrt(2.0));
  EXPECT_NEAR(t.zeroExceptionProbability() / expected, 1.0, 1e-6);
}

TEST(Detector, SaturationAndQuantisationAreExact) {
  const SensorConfig c = detectorConfig(8, 0.0);
  const Renderer r(SensorInstance::nominalOf(c));
  Rng rng(3);
  // Full well maps to the top code; more light stays there.
  cv::Mat bright(64, 64, CV_32F, cv::Scalar(3.0 * 8180.0));
  cv::Mat out = r.detect(bright, 1e-3, rng);
  double lo, hi;
  cv::minMaxLoc(out, &lo, &hi);
  EXPECT_EQ(lo, 255.0);
  EXPECT_EQ(hi, 255.0);
  // Noise off: DN = floor(e K + 0.5) exactly.
  RenderOptions quiet;
  quiet.noise = false;
  cv::Mat ramp(1, 256, CV_32F);
  for (int i = 0; i < 256; ++i) ramp.at<float>(0, i) = static_cast<float>(i * 37.3);
  out = r.detect(ramp, 1e-3, rng, quiet);
  for (int i = 0; i < 256; ++i) {
    const double e = std::min(static_cast<double>(ramp.at<float>(0, i)), 8180.0);
    EXPECT_EQ(out.at<std::uint8_t>(0, i), static_cast<int>(std::floor(e * 255.0 / 8180.0 + 0.5))) << i;
  }
}

TEST(Detector, DarkCurrentDoublesPerDoublingTemperature) {
  SensorConfig c = detectorConfig(8, 3.0);
  c.noise.dark_current_e_per_s = 100.0;
  c.noise.temperature_c = c.noise.dark_reference_temp_c + 2.0 * c.noise.dark_doubling_temp_c;
  EXPECT_NEAR(Renderer(SensorInstance::nominalOf(c)).darkElectronsPerSecond(), 400.0, 1e-9);
  // And the dark signal shows up with its Poisson statistics (12-bit, 0.5 DN/e).
  SensorConfig d = detectorConfig(12, 0.0);
  d.noise.dark_current_e_per_s = 50000.0;  // 50 e in 1 ms
  d.noise.dsnu_fraction = 0.2;
  const Renderer dark(SensorInstance::draw(d, 5));
  Rng rng(9);
  const Moments m = moments(dark.detect(cv::Mat(512, 512, CV_32F, cv::Scalar(0)), 1e-3, rng));
  const double gain = 4095.0 / 8180.0;
  EXPECT_NEAR(m.mean / (gain * 50.0), 1.0, 0.01);
  // Variance: Poisson (50 e) plus the DSNU spread (0.2 * 50 e)^2, plus rounding.
  EXPECT_NEAR(m.var / (gain * gain * (50.0 + 100.0) + 1.0 / 12.0), 1.0, 0.05);
}

TEST(Detector, ThresholdKeepsBrightPixelsAndRescales) {
  SensorConfig c = detectorConfig(8, 0.0);
  c.threshold.enabled = true;
  c.threshold.level_fraction = 0.9;
  const Renderer r(SensorInstance::nominalOf(c));
  RenderOptions quiet;
  quiet.noise = false;
  Rng rng(1);
  cv::Mat levels(1, 3, CV_32F);
  levels.at<float>(0, 0) = 0.5f * 8180.0f;  // 128 DN: dropped
  levels.at<float>(0, 1) = 0.95f * 8180.0f;  // 242 DN: kept, rescaled
  levels.at<float>(0, 2) = 8180.0f;          // 255 DN: stays 255
  const cv::Mat out = r.detect(levels, 1e-3, rng, quiet);
  EXPECT_EQ(out.at<std::uint8_t>(0, 0), 0);
  EXPECT_EQ(out.at<std::uint8_t>(0, 1), static_cast<int>(std::floor((242 - 229.5) / (255 - 229.5) * 255 + 0.5)));
  EXPECT_EQ(out.at<std::uint8_t>(0, 2), 255);
}

}  // namespace
}  // namespace dss
