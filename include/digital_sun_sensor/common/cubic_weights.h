// Catmull-Rom (bicubic, a = -1/2) interpolation weights of the four taps
// -1, 0, 1, 2 at fraction t in [0, 1), and their derivatives in t.
#pragma once

namespace dss {

inline void cubicWeights(double t, double w[4], double d[4]) {
  const double t2 = t * t, t3 = t2 * t;
  w[0] = -0.5 * t3 + t2 - 0.5 * t;
  w[1] = 1.5 * t3 - 2.5 * t2 + 1.0;
  w[2] = -1.5 * t3 + 2.0 * t2 + 0.5 * t;
  w[3] = 0.5 * t3 - 0.5 * t2;
  d[0] = -1.5 * t2 + 2.0 * t - 0.5;
  d[1] = 4.5 * t2 - 5.0 * t;
  d[2] = -4.5 * t2 + 4.0 * t + 0.5;
  d[3] = 1.5 * t2 - t;
}

}  // namespace dss
