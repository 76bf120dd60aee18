// A fresh model for a sensor: metadata, network and its physics priors.
#include "digital_sun_sensor/model/model.h"

#include "digital_sun_sensor/model/geometry_design.h"
#include "digital_sun_sensor/model/physics_prior.h"

namespace dss {

Model createModel(const SensorConfig& config, const std::string& arch_name, std::uint64_t seed) {
  return createModel(config, archPreset(arch_name, config.numSubFovClasses()), seed);
}

Model createModel(const SensorConfig& config, const ArchSpec& arch, std::uint64_t seed, const HeadOptions& head) {
  torch::manual_seed(seed);
  Model m;
  m.meta = metadataFor(config, arch, head);
  m.net = std::make_shared<SscnnNetImpl>(m.meta.arch);
  const auto [slope_x, slope_y] = centroidSlopes(config, m.meta.angle_scale_rad);
  m.net->initCentroidMap(slope_x, slope_y);
  if (m.meta.arch.geometric_prior_size > 0) {
    const GeometricPrior prior = geometricPrior(config, m.meta.arch.geometric_prior_size, m.meta.angle_scale_rad);
    m.net->initGeometricPrior(prior.table, prior.extent_x, prior.extent_y);
  }
  if (m.meta.arch.geometric_head) m.net->initGeometry(geometryDesignOf(config));
  m.net->initPattern(config, m.meta.input);
  if (m.meta.arch.apertureClassLattice()) {
    // Classes are the apertures (SubFovType::kNearestAperture), in config order.
    std::vector<std::array<double, 2>> offsets;
    std::vector<double> areas_um2;
    for (const auto& a : config.mask.apertures) {
      offsets.push_back({2.0 * a.x_um / config.detector.pitch_um / config.detector.width_px,
                         2.0 * a.y_um / config.detector.pitch_um / config.detector.height_px});
      areas_um2.push_back(a.areaUm2());
    }
    m.net->initLatticeApertures(offsets, areas_um2);
  }
  // The predicted sigma starts at half a pixel of spot motion, the error of
  // the untrained physics prior, rather than at unit variance ~16 log units
  // above the trained error level (the level is refitted after training
  // anyway: train/sigma_calibration).
  // (The pattern head's sigma starts at its solve's own.)
  if (slope_x > 0.0 && slope_y > 0.0 && !m.meta.arch.pattern_head)
    m.scaleSigma(slope_x / config.detector.width_px, slope_y / config.detector.height_px);
  return m;
}

}  // namespace dss
