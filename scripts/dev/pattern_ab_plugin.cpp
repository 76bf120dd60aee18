// One build of the pattern estimator for pattern_ab.sh, loaded with dlopen:
// make() builds it (canvases warm), one() estimates one image.
#include "digital_sun_sensor/baseline/pattern_estimator.h"

extern "C" __attribute__((visibility("default"))) void* make(const dss::SensorConfig* config) {
  dss::PatternEstimatorOptions options;
  options.sigma_images = 0;
  auto* estimator = new dss::PatternEstimator(*config, options);
  estimator->warmUp(2);
  return estimator;
}

// A check sum of the answer (the same images must give the same sums in both builds).
extern "C" __attribute__((visibility("default"))) double one(void* estimator, const cv::Mat* image) {
  const dss::SunEstimate e = static_cast<dss::PatternEstimator*>(estimator)->estimateOne(*image);
  return e.alpha_rad + e.beta_rad + 1e-3 * e.unexplained_light_z + e.covariance[0] * 1e6;
}
