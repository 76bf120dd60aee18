// Small, dependency-free plots for the credibility report, drawn with OpenCV
// and written as PNG: line plots, histograms and heat maps with axes, ticks,
// labels and legends. Deterministic (same data -> same bytes).
#pragma once

#include <opencv2/core.hpp>
#include <string>
#include <vector>

namespace dss::plot {

struct Axes {
  std::string title, x_label, y_label;
  bool log_y = false;
  // Fixed y range when y_max > y_min; else from the data.
  double y_min = 0.0, y_max = 0.0;
};

struct Series {
  std::string label;
  std::vector<double> x, y;  // non-finite points are skipped
  bool line = true, markers = true;
  bool dashed = false;
};

// Series colours follow their order (blue, orange, green, red, purple, ...).
cv::Mat lines(const Axes& axes, const std::vector<Series>& series, int width = 640, int height = 420);

// Histograms of several samples on shared bins over [lo, hi] (values outside
// go to the end bins), drawn as outlines.
cv::Mat histograms(const Axes& axes, const std::vector<std::pair<std::string, std::vector<double>>>& samples, double lo,
                   double hi, int bins = 40, int width = 640, int height = 420);

// `values` (CV_64F, row 0 at y_min; NaN = no data) over [x_min, x_max] x
// [y_min, y_max], coloured from 0 to `value_max` (viridis), with a colour bar.
cv::Mat heatMap(const Axes& axes, const cv::Mat& values, double x_min, double x_max, double y_min, double y_max,
                double value_max, const std::string& value_label, int width = 560, int height = 460);

// Writes a PNG atomically; throws std::runtime_error naming the path.
void writePng(const std::string& path, const cv::Mat& image);

}  // namespace dss::plot
