#include "digital_sun_sensor/sim/renderer.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <tuple>
#include <vector>

#include "digital_sun_sensor/common/row_runs.h"
#include "digital_sun_sensor/common/units.h"
#include "digital_sun_sensor/common/vector_clones.h"
#include "digital_sun_sensor/sim/geometry.h"
#include "digital_sun_sensor/sim/optics.h"
#include "digital_sun_sensor/sim/readout.h"
#include "digital_sun_sensor/sim/spot_cache.h"

namespace dss {
namespace {

constexpr double kPlanck = 6.62607015e-34;
constexpr double kLightSpeed = 2.99792458e8;

// Column runs [begin, end) per row: the pixels a render lights.
using RowRuns = std::vector<std::vector<std::pair<int, int>>>;

RowRuns runsOf(const cv::Mat& mask) {
  RowRuns runs(static_cast<std::size_t>(mask.rows));
  for (int r = 0; r < mask.rows; ++r)
    forEachRun(mask.ptr<std::uint8_t>(r), mask.cols,
               [&](int begin, int end) { runs[static_cast<std::size_t>(r)].emplace_back(begin, end); });
  return runs;
}

// A blend's footprint on the detector for a spot centred at (cx, cy) um:
// pixel columns [c0, c1] and rows [r0, r1], not clipped to the detector.
struct Footprint {
  int c0, c1, r0, r1;
};

Footprint footprintOf(const SpotCache::Blend& blend, double cx_um, double cy_um, double pitch_um, double half_w,
                      double half_h) {
  double u_lo = std::numeric_limits<double>::max(), u_hi = -u_lo, v_lo = u_lo, v_hi = -u_lo;
  for (int k = 0; k < blend.count; ++k) {
    const SpotMap& m = *blend.maps[k];
    u_lo = std::min(u_lo, m.u0_um);
    v_lo = std::min(v_lo, m.v0_um);
    u_hi = std::max(u_hi, m.u0_um + (m.cols - 1) * m.step_um);
    v_hi = std::max(v_hi, m.v0_um + (m.rows - 1) * m.step_um);
  }
  return {static_cast<int>(std::ceil((cx_um + u_lo) / pitch_um + half_w)),
          static_cast<int>(std::floor((cx_um + u_hi) / pitch_um + half_w)),
          static_cast<int>(std::ceil((cy_um + v_lo) / pitch_um + half_h)),
          static_cast<int>(std::floor((cy_um + v_hi) / pitch_um + half_h))};
}

// Bilinear reads of a blend's maps along pixel columns [c0, c1]: each map's
// columns that fall inside it, with their sample index and weight, once per
// spot; then row by row, each map's row and vertical weights once: the same
// bilinear lookup as SpotMap::sample, summed over the maps in order.
class BlendReader {
 public:
  BlendReader(const SpotCache::Blend& blend, int c0, int c1, double cx_um, double half_w, double pitch_um)
      : blend_(blend) {
    for (int k = 0; k < blend.count; ++k) {
      const SpotMap& m = *blend.maps[k];
      col_[k].assign(static_cast<std::size_t>(c1 - c0 + 1), 0);
      fx_[k].assign(static_cast<std::size_t>(c1 - c0 + 1), 0.0f);
      first_[k] = c1 - c0 + 1;
      last_[k] = -1;
      for (int c = c0; c <= c1; ++c) {
        const double x = ((c - half_w) * pitch_um - cx_um - m.u0_um) / m.step_um;
        if (!(x >= 0.0 && x < m.cols - 1)) continue;
        const int i = c - c0;
        first_[k] = std::min(first_[k], i);
        last_[k] = std::max(last_[k], i);
        col_[k][static_cast<std::size_t>(i)] = static_cast<int>(x);
        fx_[k][static_cast<std::size_t>(i)] = static_cast<float>(x - static_cast<int>(x));
      }
    }
  }

  // acc[from, to) (columns c0 + from ...) = the blend at v_um below the
  // spot's centre; false (acc untouched) where no map reaches that row.
  bool row(double v_um, int from, int to, float* acc) const {
    bool any = false;
    for (int k = 0; k < blend_.count; ++k) {
      const SpotMap& m = *blend_.maps[k];
      const double y = (v_um - m.v0_um) / m.step_um;
      if (!(y >= 0.0 && y < m.rows - 1)) continue;
      if (!any) std::fill(acc + from, acc + to, 0.0f);
      any = true;
      const int mr = static_cast<int>(y);
      const float fy = static_cast<float>(y - mr);
      const float* top = &m.values[static_cast<std::size_t>(mr) * m.cols];
      const float* bottom = top + m.cols;
      const float weight = blend_.weights[k];
      const int* col = col_[k].data();
      const float* frac = fx_[k].data();
      for (int i = std::max(first_[k], from), i_end = std::min(last_[k] + 1, to); i < i_end; ++i) {
        const int mc = col[i];
        const float fx = frac[i];
        acc[i] += weight * ((1.0f - fy) * ((1.0f - fx) * top[mc] + fx * top[mc + 1]) +
                            fy * ((1.0f - fx) * bottom[mc] + fx * bottom[mc + 1]));
      }
    }
    return any;
  }

 private:
  const SpotCache::Blend& blend_;
  std::array<std::vector<int>, 4> col_;
  std::array<std::vector<float>, 4> fx_;
  std::array<int, 4> first_{}, last_{};  // [first, last] of columns inside map k, relative to c0
};

// `scale` x (blended spot) centred at detector position (cx, cy) [um], read
// bilinearly row by row: a spot of its own sub-pixel phase.
class SplatSpot {
 public:
  SplatSpot(const SpotCache::Blend& blend, double cx_um, double cy_um, double scale, double pitch_um, int w, int h)
      : half_h_(0.5 * (h - 1)), pitch_um_(pitch_um), cy_um_(cy_um), scale_(scale) {
    const double half_w = 0.5 * (w - 1);
    const Footprint f = footprintOf(blend, cx_um, cy_um, pitch_um, half_w, half_h_);
    c0 = std::max(0, f.c0), c1 = std::min(w - 1, f.c1);
    r0 = std::max(0, f.r0), r1 = std::min(h - 1, f.r1);
    if (c0 <= c1) reader_.emplace(blend, c0, c1, cx_um, half_w, pitch_um);
  }

  // Adds the spot to image row r (in [r0, r1]) on columns [begin, end); acc
  // holds at least c1 - c0 + 1 values.
  void addToRow(float* row, int r, int begin, int end, float* acc) const {
    const int from = std::max(begin, c0) - c0, to = std::min(end, c1 + 1) - c0;  // [from, to) of acc
    if (to <= from || !reader_->row((r - half_h_) * pitch_um_ - cy_um_, from, to, acc)) return;
    for (int i = from; i < to; ++i) row[c0 + i] += static_cast<float>(scale_ * acc[i]);
  }

  int c0, c1, r0, r1;  // the image's columns and rows it can light (c1 < c0 or r1 < r0: none)

 private:
  double half_h_, pitch_um_, cy_um_, scale_;
  std::optional<BlendReader> reader_;
};

// A spot resampled once on the pixel grid, to be added at whole-pixel
// offsets: apertures that lie on a lattice of the pixel pitch (thesis_ca's
// coded mask) share their spots' sub-pixel phase, and each then costs one
// addition per pixel instead of a bilinear read. Its values are what
// splat() would add (scale x the blend, rounded to float the same way).
struct PixelSpot {
  Footprint at;               // where it lies when centred at its first aperture's position
  std::vector<float> values;  // (r1 - r0 + 1) x (c1 - c0 + 1)

  PixelSpot(const SpotCache::Blend& blend, double cx_um, double cy_um, double scale, double pitch_um, int w, int h) {
    const double half_w = 0.5 * (w - 1), half_h = 0.5 * (h - 1);
    at = footprintOf(blend, cx_um, cy_um, pitch_um, half_w, half_h);
    const int cols = std::max(0, at.c1 - at.c0 + 1), rows = std::max(0, at.r1 - at.r0 + 1);
    values.assign(static_cast<std::size_t>(cols) * rows, 0.0f);
    if (cols == 0) return;
    const BlendReader reader(blend, at.c0, at.c1, cx_um, half_w, pitch_um);
    std::vector<float> acc(static_cast<std::size_t>(cols));
    for (int r = at.r0; r <= at.r1; ++r) {
      if (!reader.row((r - half_h) * pitch_um - cy_um, 0, cols, acc.data())) continue;
      float* out = &values[static_cast<std::size_t>(r - at.r0) * cols];
      for (int i = 0; i < cols; ++i) out[i] = static_cast<float>(scale * acc[static_cast<std::size_t>(i)]);
    }
  }

  // Adds the spot moved by (dc, dr) pixels to image row r on each of the
  // row's runs [begin, end) (left to right) clipped to [c0, c1] (its columns
  // moved there, clipped to the image).
  void addToRow(float* row, int r, int dc, int dr, const std::vector<std::pair<int, int>>& runs, int c0, int c1) const {
    const float* in = &values[static_cast<std::size_t>(r - dr - at.r0) * (at.c1 - at.c0 + 1)] - (at.c0 + dc);
    for (const auto& [begin, end] : runs) {
      if (begin > c1) return;
      for (int c = std::max(begin, c0), c_end = std::min(end, c1 + 1); c < c_end; ++c) row[c] += in[c];
    }
  }
};

// An image's spot for an aperture shape: what is splatted (the cache's
// blend, or its composition into one map where several apertures share it)
// and its power.
struct ShapeSpot {
  int apertures = 0;
  double power_um2 = 0.0;
  SpotCache::Blend drawn;
};

// A spot of the image: its blend, centre on the detector [um] and scale.
struct SpotToAdd {
  const SpotCache::Blend* blend;
  Eigen::Vector2d centre_um;
  double scale;
};

// Adds the spots in order. Spots of one blend and scale whose centres lie
// whole pixels apart (the same sub-pixel phase to 1e-9 px) are resampled
// once (PixelSpot).
DSS_VECTOR_CLONES
void addSpots(cv::Mat& image, const std::vector<SpotToAdd>& spots, double pitch_um, const RowRuns* only) {
  constexpr double kSamePhasePx = 1e-9;
  // Per spot: the first spot of its phase group, and its offset from it [px].
  std::vector<std::size_t> first(spots.size());
  std::vector<std::array<int, 2>> offset(spots.size(), {0, 0});
  std::vector<int> members(spots.size(), 0);
  std::map<std::tuple<const SpotCache::Blend*, double, long long, long long>, std::size_t> group_of;
  for (std::size_t j = 0; j < spots.size(); ++j) {
    const Eigen::Vector2d px = spots[j].centre_um / pitch_um;
    const auto phase = [](double x) { return std::llround((x - std::floor(x)) / kSamePhasePx); };
    const std::size_t f =
        group_of.emplace(std::make_tuple(spots[j].blend, spots[j].scale, phase(px.x()), phase(px.y())), j)
            .first->second;
    const Eigen::Vector2d d = px - spots[f].centre_um / pitch_um;
    const Eigen::Vector2d whole = d.array().round();
    first[j] = (d - whole).cwiseAbs().maxCoeff() <= kSamePhasePx ? f : j;
    if (first[j] != j) offset[j] = {static_cast<int>(whole.x()), static_cast<int>(whole.y())};
    ++members[first[j]];
  }
  // Each spot that lights the image: its rows and columns there and what adds it.
  struct Placed {
    int r0, r1, c0, c1;
    const PixelSpot* pixel;  // else splat
    const SplatSpot* splat;
    int dc, dr;  // the pixel spot's move
  };
  std::vector<std::unique_ptr<PixelSpot>> resampled(spots.size());
  std::vector<std::unique_ptr<SplatSpot>> splats(spots.size());
  std::vector<Placed> placed;
  placed.reserve(spots.size());
  std::size_t widest = 0;
  for (std::size_t j = 0; j < spots.size(); ++j) {
    const SpotToAdd& s = spots[j];
    const std::size_t f = first[j];
    if (members[f] < 2) {
      splats[j] = std::make_unique<SplatSpot>(*s.blend, s.centre_um.x(), s.centre_um.y(), s.scale, pitch_um, image.cols,
                                              image.rows);
      const SplatSpot& spot = *splats[j];
      if (spot.c0 <= spot.c1 && spot.r0 <= spot.r1) {
        placed.push_back({spot.r0, spot.r1, spot.c0, spot.c1, nullptr, &spot, 0, 0});
        widest = std::max(widest, static_cast<std::size_t>(spot.c1 - spot.c0 + 1));
      }
      continue;
    }
    if (!resampled[f])
      resampled[f] = std::make_unique<PixelSpot>(*spots[f].blend, spots[f].centre_um.x(), spots[f].centre_um.y(),
                                                 spots[f].scale, pitch_um, image.cols, image.rows);
    const Footprint& at = resampled[f]->at;
    const int dc = offset[j][0], dr = offset[j][1];
    const Placed p{std::max(0, at.r0 + dr),
                   std::min(image.rows - 1, at.r1 + dr),
                   std::max(0, at.c0 + dc),
                   std::min(image.cols - 1, at.c1 + dc),
                   resampled[f].get(),
                   nullptr,
                   dc,
                   dr};
    if (p.c0 <= p.c1 && p.r0 <= p.r1) placed.push_back(p);
  }
  // Row by row, every spot on it in order (each pixel sums the spots in
  // the order given): the row stays in cache while the spots add to it;
  // spot by spot, each of thesis_ca's 117 swept a third of the image.
  thread_local std::vector<float> acc;
  acc.resize(widest);
  const std::vector<std::pair<int, int>> whole_row{{0, image.cols}};
  for (int r = 0; r < image.rows; ++r) {
    const auto& runs = only ? (*only)[static_cast<std::size_t>(r)] : whole_row;
    if (runs.empty()) continue;
    float* row = image.ptr<float>(r);
    for (const Placed& p : placed) {
      if (r < p.r0 || r > p.r1) continue;
      if (p.pixel) {
        p.pixel->addToRow(row, r, p.dc, p.dr, runs, p.c0, p.c1);
        continue;
      }
      for (const auto& [begin, end] : runs) p.splat->addToRow(row, r, begin, end, acc.data());
    }
  }
}

}  // namespace

int subFovClass(const SensorConfig& config, const ImageTruth& truth) {
  if (config.subfov == SubFovType::kQuadrant) return quadrantClass(truth.alpha_rad, truth.beta_rad);
  int best = -1;
  double best_d2 = std::numeric_limits<double>::max();
  for (const auto& s : truth.spots) {
    const double d2 = s.x_px * s.x_px + s.y_px * s.y_px;
    if (d2 < best_d2) best_d2 = d2, best = s.aperture_index;
  }
  return best;
}

Renderer::Renderer(SensorInstance instance) : instance_(std::move(instance)) {
  const auto& c = instance_.config;
  // A unit's mask height error changes its spots' diffraction, not only where they land.
  cache_ = SpotCache::shared(OpticalPath::from(c, instance_.mask_offset_um.z()), c.optics.psf_node_step_deg);
  readout_ = std::make_unique<ReadoutTable>(c.noise);
  double mean_wavelength_um = 0.0, weight_sum = 0.0;
  for (std::size_t i = 0; i < c.optics.wavelengths_um.size(); ++i) {
    mean_wavelength_um += c.optics.wavelengths_um[i] * c.optics.spectral_weights[i];
    weight_sum += c.optics.spectral_weights[i];
  }
  mean_wavelength_um /= weight_sum;
  const double photon_energy_j = kPlanck * kLightSpeed / (mean_wavelength_um * 1e-6);
  const double photons_per_m2_s = c.radiometry.irradiance_w_m2 * c.radiometry.nd_transmission / photon_energy_j;
  electron_rate_ = photons_per_m2_s * 1e-12 * c.radiometry.quantum_efficiency;
  for (const auto& aperture : instance_.apertures) shape_keys_.push_back(ApertureGeometry::from(aperture).key());
}

Renderer::~Renderer() = default;

void Renderer::warmUp(int threads, const std::function<void(std::size_t, std::size_t)>& progress) const {
  const auto& c = instance_.config;
  // The spot cache already covers one node step beyond the requested range.
  const double margin = degToRad(3.0 * c.as_built.tilt_sigma_deg);
  std::map<std::string, ApertureGeometry> unique;
  for (const auto& a : instance_.apertures) {
    const ApertureGeometry g = ApertureGeometry::from(a);
    unique.emplace(g.key(), g);
  }
  for (const auto& [key, geometry] : unique) {
    cache_->warmUp(geometry, degToRad(c.fov.alpha_max_deg) + margin, degToRad(c.fov.beta_max_deg) + margin, threads,
                   progress);
  }
}

double Renderer::darkElectronsPerSecond() const { return instance_.config.noise.darkCurrentAtTemperatureEPerS(); }

cv::Mat Renderer::expectedElectrons(const Eigen::Vector3d& sun_in, ImageTruth* truth, Rng* anomaly_rng,
                                    const cv::Mat* only, const Eigen::Vector3d* shape_sun) const {
  const SensorConfig& c = instance_.config;
  const int w = c.detector.width_px, h = c.detector.height_px;
  const double pitch = c.detector.pitch_um;
  const Eigen::Vector3d sun = sun_in.normalized();
  ImageTruth t;
  t.sun = sun;
  const SunAnglesRad angles = anglesFromSunVector(sun);
  t.alpha_rad = angles.alpha;
  t.beta_rad = angles.beta;

  const bool ghost = anomaly_rng && anomaly_rng->uniform() < c.anomalies.ghost_probability;
  const bool stray = anomaly_rng && anomaly_rng->uniform() < c.anomalies.stray_light_probability;
  t.ghost = ghost;
  t.stray_light = stray;

  if (only && (only->rows != h || only->cols != w || only->type() != CV_8U))
    throw std::invalid_argument("render: the mask of pixels to light is not a CV_8U image of the detector's size");
  const std::optional<RowRuns> runs = only ? std::optional<RowRuns>(runsOf(*only)) : std::nullopt;
  const RowRuns* lit_runs = runs ? &*runs : nullptr;
  cv::Mat rate(h, w, CV_32F, cv::Scalar(0));  // optical photoelectrons per second
  const Eigen::Vector3d sun_mask = instance_.mask_rotation.transpose() * sun;
  const Eigen::Vector3d shape_mask =
      shape_sun ? Eigen::Vector3d(instance_.mask_rotation.transpose() * shape_sun->normalized()) : sun_mask;
  // Each aperture's own height decides where its light crosses the glass
  // (a tilted mask: some above the window, some lower in it); the spot's
  // shape comes from the unit's path at the mask centre.
  const GlassSlab glass{c.cover_glass.enabled ? c.cover_glass.thickness_mm * 1000.0 : 0.0, cache_->path().glass_index};
  const double half_w_um = 0.5 * w * pitch, half_h_um = 0.5 * h * pitch;
  // One sun direction in this image: one blend per aperture shape, composed
  // once where several apertures share it (a regular mask: all of them).
  std::map<std::string, ShapeSpot> shapes;
  std::vector<SpotToAdd> spots;
  for (const auto& key : shape_keys_) ++shapes[key].apertures;
  for (std::size_t i = 0; i < instance_.apertures.size(); ++i) {
    const Eigen::Vector3d ap = instance_.apertureCentreUm(i);
    const auto hit = traceToDetector(ap, sun, glass);
    SpotTruth spot;
    spot.aperture_index = static_cast<int>(i);
    if (!hit) {
      t.spots.push_back(spot);
      continue;
    }
    spot.x_px = hit->x() / pitch;
    spot.y_px = hit->y() / pitch;
    spot.on_detector = std::abs(hit->x()) < half_w_um && std::abs(hit->y()) < half_h_um;
    const ApertureGeometry geometry = ApertureGeometry::from(instance_.apertures[i]);
    // Skip spots that cannot reach the detector at all (wide-field masks).
    const double reach_um = geometry.boundingRadiusUm() * 2.0 + 0.1 * ap.z();
    if (std::abs(hit->x()) > half_w_um + reach_um || std::abs(hit->y()) > half_h_um + reach_um) {
      t.spots.push_back(spot);
      continue;
    }
    ShapeSpot& shape = shapes.at(shape_keys_[i]);
    if (shape.drawn.count == 0) {  // the shape's first aperture on the detector
      const SpotCache::Blend blend = cache_->lookup(geometry, shape_mask);
      for (int k = 0; k < blend.count; ++k) shape.power_um2 += blend.weights[k] * blend.maps[k]->total_power_um2;
      shape.drawn = blend;
      if (shape.apertures > 1 && blend.count > 1) {
        shape.drawn = SpotCache::Blend{};
        // Into this thread's map of the last image where no blend holds it still.
        thread_local std::shared_ptr<SpotMap> composed;
        if (!composed || composed.use_count() > 1) composed = std::make_shared<SpotMap>();
        blend.composeInto(*composed);
        shape.drawn.maps[0] = composed;
        shape.drawn.weights[0] = 1.0f;
        shape.drawn.count = 1;
      }
    }
    spot.relative_flux =
        static_cast<float>(shape.power_um2 / ApertureGeometry::from(c.mask.apertures[i]).nominalAreaUm2());
    spots.push_back({&shape.drawn, *hit, electron_rate_});
    if (ghost) {
      // Detector -> mask underside -> detector: one more round trip of the
      // lateral drift, attenuated by both reflectances.
      spots.push_back(
          {&shape.drawn, *hit + 2.0 * (*hit - ap.head<2>()), electron_rate_ * c.anomalies.ghost_reflectance});
    }
    t.spots.push_back(spot);
  }
  addSpots(rate, spots, pitch, lit_runs);
  t.subfov_class = subFovClass(c, t);

  double peak_rate = 0.0;
  if (lit_runs) {
    // Nothing outside the runs was lit: the peak is theirs (a fraction of the image to read).
    for (int r = 0; r < h; ++r) {
      const float* row = rate.ptr<float>(r);
      for (const auto& [begin, end] : (*lit_runs)[static_cast<std::size_t>(r)])
        for (int c = begin; c < end; ++c) peak_rate = std::max(peak_rate, static_cast<double>(row[c]));
    }
  } else {
    cv::minMaxLoc(rate, nullptr, &peak_rate);
  }
  double exposure_s = c.exposure.exposure_s;
  if (c.exposure.mode == ExposureMode::kAuto && peak_rate > 0.0) {
    exposure_s = c.exposure.peak_fraction_of_full_well * c.noise.full_well_e / peak_rate;
  }
  t.exposure_s = exposure_s;
  cv::Mat electrons = rate;
  if (lit_runs) {  // in place, and only where light can be; in floats, as OpenCV scales a float image
    const auto scale = static_cast<float>(exposure_s);
    for (int r = 0; r < h; ++r) {
      float* row = electrons.ptr<float>(r);
      for (const auto& [begin, end] : (*lit_runs)[static_cast<std::size_t>(r)])
        for (int c = begin; c < end; ++c) row[c] *= scale;
    }
  } else {
    electrons *= exposure_s;
  }

  if (stray) {
    // Smooth gradient (Earth albedo, scattered light): amplitude and direction random.
    const double amplitude = anomaly_rng->uniform(0.0, c.anomalies.stray_light_max_fraction) * c.noise.full_well_e;
    const double slope = anomaly_rng->uniform();
    const double phi = anomaly_rng->uniform(0.0, 2.0 * M_PI);
    const double radius = std::hypot(0.5 * w, 0.5 * h);
    for (int r = 0; r < h; ++r) {
      float* row = electrons.ptr<float>(r);
      const std::uint8_t* marked = only ? only->ptr<std::uint8_t>(r) : nullptr;
      for (int col = 0; col < w; ++col) {
        if (marked && !marked[col]) continue;
        const double proj = ((col - 0.5 * (w - 1)) * std::cos(phi) + (r - 0.5 * (h - 1)) * std::sin(phi)) / radius;
        row[col] += static_cast<float>(amplitude * (1.0 - 0.5 * slope + 0.5 * slope * proj));
      }
    }
  }
  if (truth) *truth = std::move(t);
  return electrons;
}

cv::Mat Renderer::detect(const cv::Mat& signal_e, double exposure_s, Rng& rng, const RenderOptions& options) const {
  const SensorConfig& c = instance_.config;
  const auto& n = c.noise;
  const int w = signal_e.cols, h = signal_e.rows;
  const int n_px = w * h;
  const bool noise = options.noise;
  const double dark_e = noise ? darkElectronsPerSecond() * exposure_s : 0.0;
  const bool prnu = noise && !instance_.prnu_gain.empty();
  const bool dsnu = noise && !instance_.dark_scale.empty();
  // Per-thread scratch: rendering runs on several threads, each image reuses it.
  thread_local std::vector<int> codes, electrons, touched;

  const NoiseFreeReadout noise_free(c, options.threshold);
  const std::vector<int>& lut = noise_free.table();  // the on-chip threshold's, over ADC codes
  cv::Mat out(h, w, n.bit_depth <= 8 ? CV_8U : CV_16U);

  if (noise && n.shot_noise) {
    codes.resize(n_px);
    // Electron counts: Poisson(signal) where there is signal, plus dark
    // electrons as a thinned Poisson process over the whole array (sums of
    // independent Poisson variables are Poisson: the split is exact).
    electrons.assign(n_px, 0);
    touched.clear();
    for (int r = 0; r < h; ++r) {
      const float* in = signal_e.ptr<float>(r);
      for (int col = 0; col < w; ++col) {
        if (in[col] <= 0.0f) continue;
        const int idx = r * w + col;
        const double mean = prnu ? in[col] * instance_.prnu_gain[idx] : in[col];
        electrons[idx] = static_cast<int>(rng.poisson(mean));
        touched.push_back(idx);
      }
    }
    if (dark_e > 0.0) {
      const double max_scale = dsnu ? *std::max_element(instance_.dark_scale.begin(), instance_.dark_scale.end()) : 1.0;
      const double bound = dark_e * max_scale;
      const auto candidates = static_cast<std::uint64_t>(rng.poisson(bound * n_px));
      for (std::uint64_t k = 0; k < candidates; ++k) {
        const int idx = static_cast<int>(rng.below(n_px));
        const double accept = dsnu ? instance_.dark_scale[idx] / max_scale : 1.0;
        if (dsnu && rng.uniform() >= accept) continue;
        if (electrons[idx]++ == 0) touched.push_back(idx);
      }
    }
    for (const auto& hp : instance_.hot_pixels) {
      const int extra = static_cast<int>(rng.poisson(hp.dark_e_per_s * exposure_s));
      if (extra > 0 && electrons[hp.index] == 0) touched.push_back(hp.index);
      electrons[hp.index] += extra;
    }
    // Read noise + ADC through the exact per-count code distributions.
    const int full_well = static_cast<int>(n.full_well_e);
    std::fill(codes.begin(), codes.end(), readout_->zeroMode());
    const double p_exception = readout_->zeroExceptionProbability();
    if (p_exception > 0.0) {
      // Geometric skipping to the pixels whose n = 0 code is not the mode.
      const double log_q = std::log1p(-std::min(p_exception, 1.0 - 1e-12));
      for (double pos = -1.0;;) {
        pos += 1.0 + std::floor(std::log(rng.uniformPositive()) / log_q);
        if (pos >= n_px) break;
        codes[static_cast<int>(pos)] = readout_->sampleZeroException(rng);
      }
    }
    for (int idx : touched) {
      const int count = std::min(electrons[idx], full_well);  // saturation
      if (count > 0) codes[idx] = readout_->sample(count, rng);
    }
  } else {
    // Mean image (noise off) or no shot noise: direct evaluation, written
    // through the table as it goes; without noise, one value for the unlit pixels.
    if (!noise) out.setTo(noise_free.unlitCode(dark_e));
    // Light that rounds to one of the ADC codes the threshold maps onto the
    // unlit code reads so too, and is not converted (thesis_ca's design
    // images: pixels below 90 % of the peak).
    const double unlit_below_e = noise_free.unlitBelowE(dark_e);
    const bool eight_bit = out.depth() == CV_8U;
    for (int r = 0; r < h; ++r) {
      const float* in = signal_e.ptr<float>(r);
      // Row pointers taken once: an 8-bit store may alias the Mat's own fields.
      std::uint8_t* const out_8 = eight_bit ? out.ptr<std::uint8_t>(r) : nullptr;
      std::uint16_t* const out_16 = eight_bit ? nullptr : out.ptr<std::uint16_t>(r);
      auto write = [&](int col, int value) {
        if (eight_bit)
          out_8[col] = static_cast<std::uint8_t>(value);
        else
          out_16[col] = static_cast<std::uint16_t>(value);
      };
      if (!noise) {
        // Only the pixels that hold light (of `only`, where given, as no
        // other does) and read above the unlit code's run differ from it.
        auto lit = [&](int begin, int end) {
          for (int col = begin; col < end; ++col)
            if (in[col] != 0.0f && !(in[col] < unlit_below_e))
              write(col, noise_free.code(std::min(in[col] + dark_e, n.full_well_e)));
        };
        if (options.only)
          forEachRun(options.only->ptr<std::uint8_t>(r), w, lit);
        else
          lit(0, w);
        continue;
      }
      for (int col = 0; col < w; ++col) {
        const int idx = r * w + col;
        double e = (prnu ? in[col] * instance_.prnu_gain[idx] : in[col]) +
                   (dsnu ? dark_e * instance_.dark_scale[idx] : dark_e);
        e = std::min(e, n.full_well_e);
        if (n.read_noise_e > 0.0) e += n.read_noise_e * rng.normal();
        write(col, noise_free.code(e));
      }
    }
    return out;
  }

  if (out.depth() == CV_8U) {
    auto* p = out.ptr<std::uint8_t>();
    for (int i = 0; i < n_px; ++i) p[i] = static_cast<std::uint8_t>(lut[codes[i]]);
  } else {
    auto* p = out.ptr<std::uint16_t>();
    for (int i = 0; i < n_px; ++i) p[i] = static_cast<std::uint16_t>(lut[codes[i]]);
  }
  return out;
}

cv::Mat Renderer::render(const Eigen::Vector3d& sun, std::uint64_t image_seed, ImageTruth* truth,
                         const RenderOptions& options) const {
  Rng anomaly_rng(deriveSeed(image_seed, 1));
  Rng noise_rng(deriveSeed(image_seed, 2));
  ImageTruth t;
  cv::Mat electrons = expectedElectrons(sun, &t, options.anomalies ? &anomaly_rng : nullptr, options.only);
  cv::Mat image = detect(electrons, t.exposure_s, noise_rng, options);
  if (truth) *truth = std::move(t);
  return image;
}

}  // namespace dss
