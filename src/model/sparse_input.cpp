#include "digital_sun_sensor/model/sparse_input.h"

#include <algorithm>
#include <string>

#include "digital_sun_sensor/sparse/ops.h"

namespace dss {
namespace {

struct Pixel {
  int y, x;
  int dn;
};

std::vector<Pixel> activePixels(const cv::Mat& image, const InputSpec& spec) {
  std::vector<Pixel> pixels;
  for (int y = 0; y < image.rows; ++y) {
    if (image.depth() == CV_8U) {
      const auto* row = image.ptr<std::uint8_t>(y);
      for (int x = 0; x < image.cols; ++x)
        if (row[x] > spec.threshold_dn) pixels.push_back({y, x, row[x]});
    } else {
      const auto* row = image.ptr<std::uint16_t>(y);
      for (int x = 0; x < image.cols; ++x)
        if (row[x] > spec.threshold_dn) pixels.push_back({y, x, row[x]});
    }
  }
  if (static_cast<int>(pixels.size()) > spec.max_sites) {
    // Keep the brightest (ties by position, deterministic), back in row-major order.
    std::nth_element(pixels.begin(), pixels.begin() + spec.max_sites, pixels.end(), [](const Pixel& a, const Pixel& b) {
      return a.dn != b.dn ? a.dn > b.dn : (a.y != b.y ? a.y < b.y : a.x < b.x);
    });
    pixels.resize(static_cast<std::size_t>(spec.max_sites));
    std::sort(pixels.begin(), pixels.end(),
              [](const Pixel& a, const Pixel& b) { return a.y != b.y ? a.y < b.y : a.x < b.x; });
  }
  return pixels;
}

}  // namespace

sparse::SparseTensor encodeImages(const std::vector<cv::Mat>& images, const InputSpec& spec, torch::Dtype dtype) {
  std::vector<sparse::Site> sites;
  std::vector<float> features;
  const double value_scale = 1.0 / std::max(1.0, spec.max_code - spec.black_level_dn);
  const double cx = 0.5 * (spec.width_px - 1), cy = 0.5 * (spec.height_px - 1);
  const double coord_scale_x = 2.0 / spec.width_px, coord_scale_y = 2.0 / spec.height_px;
  for (std::size_t b = 0; b < images.size(); ++b) {
    try {
      spec.checkImage(images[b]);
    } catch (const std::invalid_argument& e) {
      throw std::invalid_argument("image " + std::to_string(b) + " of the batch: " + e.what());
    }
    for (const Pixel& p : activePixels(images[b], spec)) {
      sites.push_back({static_cast<std::int32_t>(b), p.y, p.x});
      features.push_back(static_cast<float>((p.dn - spec.black_level_dn) * value_scale));
      features.push_back(static_cast<float>((p.x - cx) * coord_scale_x));
      features.push_back(static_cast<float>((p.y - cy) * coord_scale_y));
    }
  }
  const auto n = static_cast<std::int64_t>(sites.size());
  auto tensor = torch::from_blob(features.data(), {n, 3}, torch::kFloat).to(dtype).clone();
  auto site_set = std::make_shared<sparse::SiteSet>(static_cast<int>(images.size()), spec.height_px, spec.width_px,
                                                    std::move(sites));
  return {tensor, site_set, std::make_shared<sparse::RulebookCache>()};
}

torch::Tensor encodeImagesDense(const std::vector<cv::Mat>& images, const InputSpec& spec) {
  const auto s = encodeImages(images, spec);
  return sparse::toDense(s.features, *s.sites);
}

}  // namespace dss
