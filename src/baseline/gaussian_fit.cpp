#include "digital_sun_sensor/baseline/gaussian_fit.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <vector>

namespace dss {
namespace {

constexpr double kInvSqrt2 = 0.70710678118654752440;
constexpr double kInvSqrt2Pi = 0.39894228040143267794;

double normalCdf(double z) { return 0.5 * std::erfc(-z * kInvSqrt2); }
double normalPdf(double z) { return kInvSqrt2Pi * std::exp(-0.5 * z * z); }

// One axis of the pixel-integrated Gaussian and its derivatives.
struct AxisTerm {
  double value, d_centre, d_sigma;
};

AxisTerm axisTerm(double pixel, double centre, double sigma) {
  const double a = (pixel - 0.5 - centre) / sigma, b = (pixel + 0.5 - centre) / sigma;
  const double pa = normalPdf(a), pb = normalPdf(b);
  return {normalCdf(b) - normalCdf(a), -(pb - pa) / sigma, -(b * pb - a * pa) / sigma};
}

enum Param { kX, kY, kSigma, kTotal, kBackground, kNumParams };

}  // namespace

double gaussianPixelMean(const GaussianSpot& spot, int col, int row) {
  return spot.background +
         spot.total * axisTerm(col, spot.x, spot.sigma).value * axisTerm(row, spot.y, spot.sigma).value;
}

cv::Mat renderGaussianSpot(const GaussianSpot& spot, int rows, int cols) {
  cv::Mat out(rows, cols, CV_64F);
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) out.at<double>(r, c) = gaussianPixelMean(spot, c, r);
  return out;
}

GaussianFitResult fitGaussianSpot(const cv::Mat& counts, const GaussianSpot& start, const GaussianFitOptions& options) {
  CV_Assert(counts.type() == CV_64FC1);
  const int rows = counts.rows, cols = counts.cols;
  const double shift = options.read_noise * options.read_noise;
  std::vector<bool> free_param(kNumParams, true);
  free_param[kSigma] = options.fit_sigma;
  free_param[kBackground] = options.fit_background;

  auto toVector = [](const GaussianSpot& s) {
    Eigen::Matrix<double, kNumParams, 1> p;
    p << s.x, s.y, s.sigma, s.total, s.background;
    return p;
  };
  auto toSpot = [](const Eigen::Matrix<double, kNumParams, 1>& p) {
    return GaussianSpot{p[kX], p[kY], p[kSigma], p[kTotal], p[kBackground]};
  };
  // Negative shifted-Poisson log-likelihood (up to a constant).
  auto nll = [&](const GaussianSpot& s) {
    double sum = 0.0;
    for (int r = 0; r < rows; ++r) {
      const double y_term = axisTerm(r, s.y, s.sigma).value;
      for (int c = 0; c < cols; ++c) {
        const double m = std::max(1e-12, s.background + s.total * axisTerm(c, s.x, s.sigma).value * y_term + shift);
        const double d = std::max(0.0, counts.at<double>(r, c) + shift);
        sum += m - d * std::log(m);
      }
    }
    return sum;
  };

  GaussianFitResult result;
  result.spot = start;
  double current = nll(start);
  double lambda = 1e-3;
  for (int it = 0; it < options.max_iterations; ++it) {
    result.iterations = it + 1;
    const GaussianSpot& s = result.spot;
    // Fisher scoring: H = sum J^T J / m, g = sum J (1 - d / m).
    Eigen::Matrix<double, kNumParams, kNumParams> h = Eigen::Matrix<double, kNumParams, kNumParams>::Zero();
    Eigen::Matrix<double, kNumParams, 1> g = Eigen::Matrix<double, kNumParams, 1>::Zero();
    std::vector<AxisTerm> tx(cols);
    for (int c = 0; c < cols; ++c) tx[c] = axisTerm(c, s.x, s.sigma);
    for (int r = 0; r < rows; ++r) {
      const AxisTerm ty = axisTerm(r, s.y, s.sigma);
      for (int c = 0; c < cols; ++c) {
        const double shape = tx[c].value * ty.value;
        const double m = std::max(1e-12, s.background + s.total * shape + shift);
        const double d = std::max(0.0, counts.at<double>(r, c) + shift);
        Eigen::Matrix<double, kNumParams, 1> j;
        j << s.total * tx[c].d_centre * ty.value, s.total * tx[c].value * ty.d_centre,
            s.total * (tx[c].d_sigma * ty.value + tx[c].value * ty.d_sigma), shape, 1.0;
        for (int k = 0; k < kNumParams; ++k)
          if (!free_param[k]) j[k] = 0.0;
        h.noalias() += j * j.transpose() / m;
        g.noalias() += j * (1.0 - d / m);
      }
    }
    for (int k = 0; k < kNumParams; ++k)
      if (!free_param[k]) h(k, k) = 1.0;
    bool accepted = false;
    Eigen::Matrix<double, kNumParams, 1> step;
    for (int attempt = 0; attempt < 12 && !accepted; ++attempt) {
      Eigen::Matrix<double, kNumParams, kNumParams> damped = h;
      damped.diagonal() *= 1.0 + lambda;
      step = -damped.ldlt().solve(g);
      Eigen::Matrix<double, kNumParams, 1> p = toVector(s) + step;
      p[kSigma] = std::max(0.05, p[kSigma]);
      p[kTotal] = std::max(1e-9, p[kTotal]);
      const GaussianSpot candidate = toSpot(p);
      const double value = nll(candidate);
      if (std::isfinite(value) && value <= current) {
        result.spot = candidate;
        current = value;
        lambda = std::max(1e-7, lambda * 0.3);
        accepted = true;
      } else {
        lambda *= 10.0;
      }
    }
    // No further decrease possible, or the centre has settled.
    if (!accepted || (std::abs(step[kX]) < 1e-7 && std::abs(step[kY]) < 1e-7)) {
      result.converged = true;
      break;
    }
  }
  return result;
}

}  // namespace dss
