#include "digital_sun_sensor/eval/plot.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

#include "digital_sun_sensor/common/file_io.h"

namespace dss::plot {
namespace {

const cv::Scalar kWhite(255, 255, 255), kBlack(0, 0, 0), kGrid(225, 225, 225);
constexpr int kFont = cv::FONT_HERSHEY_SIMPLEX;
constexpr double kSmall = 0.4, kTitle = 0.5;

// Matplotlib's tab10, BGR.
cv::Scalar colour(std::size_t i) {
  static const cv::Scalar palette[] = {{180, 119, 31},  {14, 127, 255}, {44, 160, 44},   {40, 39, 214},
                                       {189, 103, 148}, {75, 86, 140},  {194, 119, 227}, {127, 127, 127}};
  return palette[i % 8];
}

std::string format(double v) {
  char buf[32];
  const double a = std::abs(v);
  if (v == 0.0) return "0";
  if (a >= 1e4 || a < 1e-3) {
    std::snprintf(buf, sizeof buf, "%.0e", v);
  } else {
    std::snprintf(buf, sizeof buf, "%.4g", v);
  }
  return buf;
}

// About `n` round tick values (1, 2, 5 x 10^k steps) covering [lo, hi].
std::vector<double> ticks(double lo, double hi, int n = 5) {
  if (!(hi > lo)) return {lo};
  const double raw = (hi - lo) / n, mag = std::pow(10.0, std::floor(std::log10(raw)));
  const double step = raw / mag < 1.5 ? mag : raw / mag < 3.5 ? 2 * mag : raw / mag < 7.5 ? 5 * mag : 10 * mag;
  std::vector<double> out;
  for (double t = std::ceil(lo / step - 1e-9) * step; t <= hi + 1e-9 * step; t += step)
    out.push_back(std::abs(t) < 1e-12 * step ? 0.0 : t);
  return out;
}

void text(cv::Mat& img, const std::string& s, cv::Point p, double scale = kSmall, int align = 0,
          bool vertical = false) {
  int base = 0;
  const cv::Size size = cv::getTextSize(s, kFont, scale, 1, &base);
  if (!vertical) {
    p.x -= align == 0 ? 0 : align == 1 ? size.width / 2 : size.width;
    cv::putText(img, s, p, kFont, scale, kBlack, 1, cv::LINE_AA);
    return;
  }
  cv::Mat patch(size.height + base + 2, size.width + 2, img.type(), kWhite);
  cv::putText(patch, s, {1, size.height}, kFont, scale, kBlack, 1, cv::LINE_AA);
  cv::rotate(patch, patch, cv::ROTATE_90_COUNTERCLOCKWISE);
  const cv::Rect r(p.x - patch.cols / 2, p.y - patch.rows / 2, patch.cols, patch.rows);
  if ((r & cv::Rect(0, 0, img.cols, img.rows)) == r) patch.copyTo(img(r));
}

// Plot area with axes, grid, ticks and labels; maps data to pixels.
struct Frame {
  cv::Mat img;
  cv::Rect area;
  double x0, x1, y0, y1;
  bool log_y;

  Frame(const Axes& axes, int width, int height, double xa, double xb, double ya, double yb, int right_margin = 20)
      : img(height, width, CV_8UC3, kWhite), log_y(axes.log_y) {
    area = cv::Rect(72, 34, width - 72 - right_margin, height - 34 - 52);
    if (!(xb > xa)) xa -= 0.5, xb += 0.5;
    if (axes.y_max > axes.y_min) ya = axes.y_min, yb = axes.y_max;
    if (log_y) {
      ya = std::log10(std::max(ya, 1e-12));
      yb = std::log10(std::max(yb, 1e-12));
      ya = std::floor(ya), yb = std::ceil(yb);
    }
    if (!(yb > ya)) ya -= 0.5, yb += 0.5;
    x0 = xa, x1 = xb, y0 = ya, y1 = yb;
    for (double t : ticks(x0, x1)) {
      const int px = X(t);
      cv::line(img, {px, area.y}, {px, area.br().y}, kGrid);
      cv::line(img, {px, area.br().y}, {px, area.br().y + 4}, kBlack);
      text(img, format(t), {px, area.br().y + 17}, kSmall, 1);
    }
    const std::vector<double> yt = log_y ? ticks(y0, y1, static_cast<int>(y1 - y0)) : ticks(y0, y1);
    for (double t : yt) {
      const int py = Yraw(t);
      cv::line(img, {area.x, py}, {area.br().x, py}, kGrid);
      cv::line(img, {area.x - 4, py}, {area.x, py}, kBlack);
      text(img, format(log_y ? std::pow(10.0, t) : t), {area.x - 7, py + 4}, kSmall, 2);
    }
    cv::rectangle(img, area, kBlack);
    text(img, axes.title, {width / 2, 22}, kTitle, 1);
    text(img, axes.x_label, {area.x + area.width / 2, height - 12}, kSmall, 1);
    text(img, axes.y_label, {14, area.y + area.height / 2}, kSmall, 0, true);
  }
  int X(double x) const { return area.x + static_cast<int>(std::lround((x - x0) / (x1 - x0) * area.width)); }
  int Yraw(double y) const { return area.br().y - static_cast<int>(std::lround((y - y0) / (y1 - y0) * area.height)); }
  bool valid(double x, double y) const { return std::isfinite(x) && std::isfinite(y) && (!log_y || y > 0.0); }
  cv::Point P(double x, double y) const {
    const double v = log_y ? std::log10(y) : y;
    return {X(x), std::clamp(Yraw(v), area.y, area.br().y)};
  }
  void legend(const std::vector<std::string>& labels) {
    int y = area.y + 16;
    for (std::size_t i = 0; i < labels.size(); ++i, y += 16) {
      if (labels[i].empty()) continue;
      const int x = area.br().x - 150;
      cv::line(img, {x, y - 4}, {x + 22, y - 4}, colour(i), 2, cv::LINE_AA);
      text(img, labels[i], {x + 28, y});
    }
  }
};

void range(const std::vector<double>& v, double& lo, double& hi, bool positive_only = false) {
  for (double x : v) {
    if (!std::isfinite(x) || (positive_only && x <= 0.0)) continue;
    lo = std::min(lo, x);
    hi = std::max(hi, x);
  }
}

}  // namespace

cv::Mat lines(const Axes& axes, const std::vector<Series>& series, int width, int height) {
  double xa = std::numeric_limits<double>::max(), xb = -xa, ya = xa, yb = -xa;
  for (const auto& s : series) {
    range(s.x, xa, xb);
    range(s.y, ya, yb, axes.log_y);
  }
  if (xa > xb) xa = 0, xb = 1;
  if (ya > yb) ya = axes.log_y ? 1e-3 : 0, yb = 1;
  if (!axes.log_y) ya = std::min(ya, 0.0);
  Frame f(axes, width, height, xa, xb, ya, yb + (axes.log_y ? 0.0 : 0.08 * (yb - ya)));
  std::vector<std::string> labels;
  for (std::size_t i = 0; i < series.size(); ++i) {
    const Series& s = series[i];
    labels.push_back(s.label);
    cv::Point last(-1, -1);
    for (std::size_t k = 0; k < std::min(s.x.size(), s.y.size()); ++k) {
      if (!f.valid(s.x[k], s.y[k])) {
        last = {-1, -1};
        continue;
      }
      const cv::Point p = f.P(s.x[k], s.y[k]);
      if (s.line && last.x >= 0) {
        if (s.dashed) {
          const int n = std::max(1, static_cast<int>(cv::norm(p - last) / 6));
          for (int j = 0; j < n; j += 2)
            cv::line(f.img, last + (p - last) * j / n, last + (p - last) * (j + 1) / n, colour(i), 2, cv::LINE_AA);
        } else {
          cv::line(f.img, last, p, colour(i), 2, cv::LINE_AA);
        }
      }
      if (s.markers) cv::circle(f.img, p, 3, colour(i), cv::FILLED, cv::LINE_AA);
      last = p;
    }
  }
  f.legend(labels);
  return f.img;
}

cv::Mat histograms(const Axes& axes, const std::vector<std::pair<std::string, std::vector<double>>>& samples, double lo,
                   double hi, int bins, int width, int height) {
  if (!(hi > lo) || bins < 1) throw std::invalid_argument("plot::histograms: empty range or no bins");
  std::vector<std::vector<double>> counts;
  double top = 0.0;
  for (const auto& [label, values] : samples) {
    std::vector<double> c(bins, 0.0);
    for (double v : values) {
      if (!std::isfinite(v)) continue;
      const int b = std::clamp(static_cast<int>((v - lo) / (hi - lo) * bins), 0, bins - 1);
      c[b] += 1.0;
    }
    for (double& x : c) x /= std::max<std::size_t>(1, values.size());  // fraction per bin
    top = std::max(top, *std::max_element(c.begin(), c.end()));
    counts.push_back(c);
  }
  Frame f(axes, width, height, lo, hi, 0.0, top > 0 ? 1.1 * top : 1.0);
  std::vector<std::string> labels;
  for (std::size_t i = 0; i < counts.size(); ++i) {
    labels.push_back(samples[i].first);
    cv::Point last = f.P(lo, 0.0);
    for (int b = 0; b < bins; ++b) {
      const double xa = lo + (hi - lo) * b / bins, xb = lo + (hi - lo) * (b + 1) / bins;
      const cv::Point a = f.P(xa, counts[i][b]), c = f.P(xb, counts[i][b]);
      cv::line(f.img, last, a, colour(i), 2, cv::LINE_AA);
      cv::line(f.img, a, c, colour(i), 2, cv::LINE_AA);
      last = c;
    }
    cv::line(f.img, last, f.P(hi, 0.0), colour(i), 2, cv::LINE_AA);
  }
  f.legend(labels);
  return f.img;
}

cv::Mat heatMap(const Axes& axes, const cv::Mat& values, double x_min, double x_max, double y_min, double y_max,
                double value_max, const std::string& value_label, int width, int height) {
  if (values.type() != CV_64F || values.empty()) throw std::invalid_argument("plot::heatMap: values must be CV_64F");
  Frame f(axes, width, height, x_min, x_max, y_min, y_max, 110);
  cv::Mat scaled(values.size(), CV_8U), mask(values.size(), CV_8U);
  for (int r = 0; r < values.rows; ++r) {
    for (int c = 0; c < values.cols; ++c) {
      const double v = values.at<double>(r, c);
      mask.at<std::uint8_t>(r, c) = std::isfinite(v) ? 255 : 0;
      scaled.at<std::uint8_t>(r, c) =
          static_cast<std::uint8_t>(std::clamp(std::isfinite(v) ? v / value_max * 255.0 : 0.0, 0.0, 255.0));
    }
  }
  cv::Mat coloured;
  cv::applyColorMap(scaled, coloured, cv::COLORMAP_VIRIDIS);
  coloured.setTo(cv::Scalar(235, 235, 235), mask == 0);
  cv::flip(coloured, coloured, 0);  // row 0 (y_min) at the bottom
  cv::Mat resized;
  cv::resize(coloured, resized, f.area.size(), 0, 0, cv::INTER_NEAREST);
  resized.copyTo(f.img(f.area));
  cv::rectangle(f.img, f.area, kBlack);
  // Colour bar.
  const cv::Rect bar(f.area.br().x + 18, f.area.y, 16, f.area.height);
  cv::Mat ramp(bar.height, 1, CV_8U);
  for (int r = 0; r < bar.height; ++r)
    ramp.at<std::uint8_t>(r) = static_cast<std::uint8_t>(255 - 255 * r / (bar.height - 1));
  cv::Mat ramp_colour;
  cv::applyColorMap(ramp, ramp_colour, cv::COLORMAP_VIRIDIS);
  cv::resize(ramp_colour, ramp_colour, bar.size(), 0, 0, cv::INTER_NEAREST);
  ramp_colour.copyTo(f.img(bar));
  cv::rectangle(f.img, bar, kBlack);
  for (double t : ticks(0.0, value_max, 4)) {
    const int py = bar.br().y - static_cast<int>(std::lround(t / value_max * bar.height));
    text(f.img, format(t), {bar.br().x + 4, py + 4});
  }
  text(f.img, value_label, {bar.x + 8, bar.br().y + 30}, kSmall, 1);
  return f.img;
}

void writePng(const std::string& path, const cv::Mat& image) {
  std::vector<std::uint8_t> bytes;
  if (!cv::imencode(".png", image, bytes)) throw std::runtime_error("could not encode PNG for " + path);
  writeFileAtomic(path, std::string(bytes.begin(), bytes.end()));
}

}  // namespace dss::plot
