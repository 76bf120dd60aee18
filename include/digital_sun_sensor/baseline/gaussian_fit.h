// Pixel-integrated 2D Gaussian spot model and its maximum-likelihood fit under
// Poisson + Gaussian read noise (the shifted-Poisson approximation: n + r^2 is
// treated as Poisson with mean mu + r^2, exact for r = 0). With enough photons
// this estimator is efficient: its variance reaches the Cramer-Rao bound.
#pragma once

#include <opencv2/core.hpp>

namespace dss {

struct GaussianSpot {
  double x = 0.0;  // centre [px], in the patch's column coordinates (pixel centres at integers)
  double y = 0.0;
  double sigma = 1.0;       // [px]
  double total = 0.0;       // integrated signal (all pixels, to infinity)
  double background = 0.0;  // per pixel
};

// Expected value of pixel (col, row): background + total x the Gaussian's
// integral over the unit pixel centred there.
double gaussianPixelMean(const GaussianSpot& spot, int col, int row);

// Expected image (CV_64F) of `spot` over a rows x cols patch.
cv::Mat renderGaussianSpot(const GaussianSpot& spot, int rows, int cols);

struct GaussianFitOptions {
  double read_noise = 0.0;  // same units as the data
  bool fit_sigma = true;
  bool fit_background = true;
  int max_iterations = 50;
};

struct GaussianFitResult {
  GaussianSpot spot;
  bool converged = false;
  int iterations = 0;
};

// Fits `counts` (CV_64F, one channel, photoelectron-like units) from `start`.
GaussianFitResult fitGaussianSpot(const cv::Mat& counts, const GaussianSpot& start,
                                  const GaussianFitOptions& options = {});

}  // namespace dss
