#include "digital_sun_sensor/model/sparse_input.h"

#include <algorithm>
#include <string>

#include "digital_sun_sensor/sparse/ops.h"

namespace dss {
namespace {

using Pixel = ActivePixel;

void sortRowMajor(std::vector<Pixel>& pixels) {
  std::sort(pixels.begin(), pixels.end(),
            [](const Pixel& a, const Pixel& b) { return a.y != b.y ? a.y < b.y : a.x < b.x; });
}

// Keeps the brightest spec.max_sites pixels (ties by position, deterministic), in row-major order.
void limitSites(std::vector<Pixel>& pixels, const InputSpec& spec) {
  if (static_cast<int>(pixels.size()) <= spec.max_sites) return;
  std::nth_element(pixels.begin(), pixels.begin() + spec.max_sites, pixels.end(), [](const Pixel& a, const Pixel& b) {
    return a.dn != b.dn ? a.dn > b.dn : (a.y != b.y ? a.y < b.y : a.x < b.x);
  });
  pixels.resize(static_cast<std::size_t>(spec.max_sites));
  sortRowMajor(pixels);
}

std::vector<Pixel> activePixels(const cv::Mat& image, const InputSpec& spec) {
  std::vector<Pixel> pixels = pixelsAboveThreshold(image, spec);
  limitSites(pixels, spec);
  return pixels;
}

// Accumulates the sites and features (value, x, y) of a batch, image by image.
class BatchEncoder {
 public:
  explicit BatchEncoder(const InputSpec& spec)
      : spec_(spec),
        value_scale_(1.0 / std::max(1.0, spec.max_code - spec.black_level_dn)),
        cx_(0.5 * (spec.width_px - 1)),
        cy_(0.5 * (spec.height_px - 1)) {}

  // The image once per transform, each its own batch entry.
  void addImage(const std::vector<Pixel>& pixels, const std::vector<PixelTransform>& transforms) {
    for (const PixelTransform& t : transforms) {
      if (!t.transpose && !t.flip_x && !t.flip_y) {
        addImage(pixels);
        continue;
      }
      mirrored_ = pixels;
      for (Pixel& p : mirrored_) t.apply(p.x, p.y, spec_.width_px, spec_.height_px);
      sortRowMajor(mirrored_);
      addImage(mirrored_);
    }
  }

  void addImage(const std::vector<Pixel>& pixels) {
    for (const Pixel& p : pixels) {
      sites_.push_back({images_, p.y, p.x});
      features_.push_back(static_cast<float>((p.dn - spec_.black_level_dn) * value_scale_));
      features_.push_back(static_cast<float>((p.x - cx_) * 2.0 / spec_.width_px));
      features_.push_back(static_cast<float>((p.y - cy_) * 2.0 / spec_.height_px));
    }
    ++images_;
  }

  sparse::SparseTensor finish(torch::Dtype dtype) {
    const auto n = static_cast<std::int64_t>(sites_.size());
    auto tensor = torch::from_blob(features_.data(), {n, 3}, torch::kFloat).to(dtype).clone();
    auto site_set = std::make_shared<sparse::SiteSet>(images_, spec_.height_px, spec_.width_px, std::move(sites_));
    return {tensor, site_set, std::make_shared<sparse::RulebookCache>()};
  }

 private:
  const InputSpec& spec_;
  double value_scale_, cx_, cy_;
  std::int32_t images_ = 0;
  std::vector<sparse::Site> sites_;
  std::vector<float> features_;
  std::vector<Pixel> mirrored_;  // reused between images
};

}  // namespace

void checkImages(const std::vector<cv::Mat>& images, const InputSpec& spec) {
  for (std::size_t b = 0; b < images.size(); ++b) {
    try {
      spec.checkImage(images[b]);
    } catch (const std::invalid_argument& e) {
      throw std::invalid_argument("image " + std::to_string(b) + " of the batch: " + e.what());
    }
  }
}

sparse::SparseTensor encodeImages(const std::vector<cv::Mat>& images, const InputSpec& spec, torch::Dtype dtype,
                                  InferenceSymmetry symmetry) {
  checkImages(images, spec);
  BatchEncoder encoder(spec);
  const std::vector<PixelTransform> transforms = symmetryTransforms(symmetry);
  for (const cv::Mat& image : images) encoder.addImage(activePixels(image, spec), transforms);
  return encoder.finish(dtype);
}

sparse::SparseTensor encodeSamples(const std::vector<const SparseSample*>& samples, const InputSpec& spec,
                                   InferenceSymmetry symmetry) {
  BatchEncoder encoder(spec);
  const std::vector<PixelTransform> transforms = symmetryTransforms(symmetry);
  std::vector<Pixel> pixels;
  for (const SparseSample* s : samples) {
    pixels.clear();
    for (std::size_t i = 0; i < s->pixels.size(); ++i)
      if (s->dn[i] > spec.threshold_dn)
        pixels.push_back({static_cast<int>(s->pixels[i] >> 16), static_cast<int>(s->pixels[i] & 0xFFFF), s->dn[i]});
    limitSites(pixels, spec);
    encoder.addImage(pixels, transforms);
  }
  return encoder.finish(torch::kFloat);
}

namespace {

// Pixels above the threshold copied into `out` (of its depth, zeroed), their count returned.
template <typename In, typename Out>
int copyAboveThreshold(const cv::Mat& image, double threshold_dn, cv::Mat& out) {
  int count = 0;
  for (int y = 0; y < image.rows; ++y) {
    const In* from = image.ptr<In>(y);
    Out* to = out.ptr<Out>(y);
    for (int x = 0; x < image.cols; ++x)
      if (from[x] > threshold_dn) {
        to[x] = static_cast<Out>(from[x]);
        ++count;
      }
  }
  return count;
}

}  // namespace

cv::Mat siteImage(const cv::Mat& image, const InputSpec& spec, int& sites) {
  spec.checkImage(image);
  const bool wide = spec.max_code > 255;
  cv::Mat out = cv::Mat::zeros(image.rows, image.cols, wide ? CV_16U : CV_8U);
  const bool eight_bit = image.depth() == CV_8U;
  sites = eight_bit ? (wide ? copyAboveThreshold<std::uint8_t, std::uint16_t>(image, spec.threshold_dn, out)
                            : copyAboveThreshold<std::uint8_t, std::uint8_t>(image, spec.threshold_dn, out))
                    : (wide ? copyAboveThreshold<std::uint16_t, std::uint16_t>(image, spec.threshold_dn, out)
                            : copyAboveThreshold<std::uint16_t, std::uint8_t>(image, spec.threshold_dn, out));
  if (sites <= spec.max_sites) return out;
  // Beyond max_sites: only the brightest, as encodeImages keeps them.
  out.setTo(0);
  const std::vector<Pixel> kept = activePixels(image, spec);
  for (const Pixel& p : kept) {
    if (wide)
      out.at<std::uint16_t>(p.y, p.x) = static_cast<std::uint16_t>(p.dn);
    else
      out.at<std::uint8_t>(p.y, p.x) = static_cast<std::uint8_t>(p.dn);
  }
  sites = static_cast<int>(kept.size());
  return out;
}

torch::Tensor encodeImagesDense(const std::vector<cv::Mat>& images, const InputSpec& spec) {
  const auto s = encodeImages(images, spec);
  return sparse::toDense(s.features, *s.sites);
}

}  // namespace dss
