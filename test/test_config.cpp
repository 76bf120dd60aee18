// Sensor configs: the shipped ones load; every kind of bad config gets an
// error that names the file and the key.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdio>
#include <fstream>
#include <regex>
#include <sstream>

#include "digital_sun_sensor/sim/sensor_config.h"

namespace dss {
namespace {

std::string shipped(const std::string& name) {
  return std::string(DSS_SOURCE_DIR) + "/config/sensors/" + name + ".yaml";
}

std::string readFile(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// Error message of parsing `text`, or "" when it parses.
std::string errorOf(const std::string& text, const std::vector<std::string>& overrides = {}) {
  try {
    parseSensorConfig(text, "bad.yaml", overrides);
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

TEST(SensorConfig, ShippedConfigsLoad) {
  const SensorConfig sa = loadSensorConfig(shipped("thesis_sa"));
  EXPECT_EQ(sa.name, "thesis_sa");
  EXPECT_EQ(sa.mask.apertures.size(), 1u);
  EXPECT_DOUBLE_EQ(sa.mask.height_mm, 5.0);
  EXPECT_DOUBLE_EQ(sa.detector.pitch_um, 1.55);
  EXPECT_EQ(loadSensorConfig(shipped("thesis_ma")).mask.apertures.size(), 9u);
  EXPECT_EQ(loadSensorConfig(shipped("thesis_ca")).mask.apertures.size(), 117u);
  const SensorConfig wide = loadSensorConfig(shipped("wide_ma"));
  EXPECT_EQ(wide.mask.apertures.size(), 49u);
  EXPECT_TRUE(wide.cover_glass.enabled);
  EXPECT_EQ(wide.numSubFovClasses(), 49);
}

TEST(SensorConfig, RoundTripsThroughCanonicalYaml) {
  const SensorConfig a = loadSensorConfig(shipped("wide_ma"));
  const SensorConfig b = parseSensorConfig(toYaml(a), "roundtrip");
  EXPECT_EQ(toYaml(a), toYaml(b));
}

// One key table reads and writes (sim/sensor_config_fields.h): a config of the
// required keys alone is written whole, every optional key at its default, and
// what is written reads back the same; a square aperture is written as the
// rectangle it is read as.
TEST(SensorConfig, OneKeyTableReadsAndWritesEveryKey) {
  const std::string minimal =
      "name: tiny\n"
      "detector: {width_px: 64, height_px: 48, pitch_um: 5.0}\n"
      "mask: {height_mm: 2.0, apertures: [{diameter_um: 40}, {shape: square, side_um: 30, x_um: 500}]}\n"
      "optics: {wavelengths_um: [0.6], spectral_weights: [1]}\n"
      "detector_noise: {full_well_e: 5000}\n"
      "fov: {alpha_max_deg: 5, beta_max_deg: 5}\n";
  const SensorConfig c = parseSensorConfig(minimal, "minimal.yaml");
  const std::string written = toYaml(c);
  const SensorConfig d = parseSensorConfig(written, "written.yaml");
  EXPECT_EQ(toYaml(d), written);
  for (const std::string key :
       {"thickness_mm: 0", "refractive_index: 1.5", "mode: fresnel", "limb_darkening_u: 0.56", "grid_size: 512",
        "irradiance_w_m2: 1361", "mode: auto", "adc_full_scale_e: 5000", "bit_depth: 8", "level_fraction: 0.9",
        "aperture_diameter_sigma_um: 0", "max_fraction: 0.2", "max_e_per_s: 1e+07", "max_blocked_fraction: 0.3",
        "reflectance: 0.02", "subfov: quadrant"})
    EXPECT_NE(written.find(key), std::string::npos) << key << " not written:\n" << written;
  ASSERT_EQ(d.mask.apertures.size(), 2u);
  EXPECT_EQ(d.mask.apertures[1].shape, ApertureShape::kRectangle);
  EXPECT_DOUBLE_EQ(d.mask.apertures[1].width_um, 30.0);
  EXPECT_DOUBLE_EQ(d.mask.apertures[1].height_um, 30.0);
  EXPECT_DOUBLE_EQ(d.mask.apertures[1].x_um, 500.0);
  EXPECT_DOUBLE_EQ(d.noise.adc_full_scale_e, 5000.0);  // the full well unless given
}

TEST(SensorConfig, OverridesApply) {
  const SensorConfig c = loadSensorConfig(shipped("thesis_sa"), {"optics.mode=far_field", "mask.height_mm=4.5"});
  EXPECT_EQ(c.optics.mode, OpticsMode::kFarField);
  EXPECT_DOUBLE_EQ(c.mask.height_mm, 4.5);
  EXPECT_NE(errorOf(readFile(shipped("thesis_sa")), {"no_equals_sign"}).find("expected key.path=value"),
            std::string::npos);
}

TEST(SensorConfig, BadConfigsNameFileAndKey) {
  const std::string good = readFile(shipped("thesis_sa"));
  auto replaced = [&](const std::string& from, const std::string& to) {
    std::string s = good;
    const auto pos = s.find(from);
    EXPECT_NE(pos, std::string::npos) << from;
    return s.replace(pos, from.size(), to);
  };
  auto expectError = [](const std::string& message, const std::vector<std::string>& needles) {
    ASSERT_FALSE(message.empty()) << "expected an error";
    EXPECT_EQ(message.rfind("bad.yaml: ", 0), 0u) << message;
    for (const auto& n : needles) EXPECT_NE(message.find(n), std::string::npos) << message << " lacks " << n;
  };
  // Missing key.
  expectError(errorOf(replaced("  height_mm: 5.0", "")), {"mask.height_mm", "missing"});
  // Missing section.
  expectError(errorOf(replaced("fov: {alpha_max_deg: 4.54, beta_max_deg: 4.54}", "")), {"fov", "missing"});
  // Wrong type.
  expectError(errorOf(replaced("width_px: 512", "width_px: wide")), {"detector.width_px", "wrong type"});
  // Negative size.
  expectError(errorOf(replaced("pitch_um: 1.55", "pitch_um: -1.55")), {"detector.pitch_um", "> 0"});
  expectError(errorOf(replaced("diameter_um: 100.0", "diameter_um: -5")), {"mask.apertures[0].diameter_um"});
  // Unknown aperture shape.
  expectError(errorOf(replaced("shape: circle", "shape: hexagon")), {"mask.apertures[0].shape", "hexagon"});
  // Mismatched spectrum.
  expectError(errorOf(replaced("[0.444, 1.0, 0.788, 0.688, 0.356]", "[1.0]")), {"optics.spectral_weights"});
  // Unknown enum value.
  expectError(errorOf(replaced("mode: fresnel", "mode: ray_tracing")), {"optics.mode", "ray_tracing"});
  // Malformed YAML, with its line.
  expectError(errorOf("name: x\ndetector: {width_px: 512\n"), {"malformed YAML", "line"});
  expectError(errorOf("- just\n- a list\n"), {"mapping"});
  // A misspelt optional key, at the top level, in a section and in an aperture, is refused with its path.
  expectError(errorOf(replaced("  height_mm: 5.0", "  height_mm: 5.0\n  thicknes_mm: 0.1")),
              {"mask.thicknes_mm: unknown key", "thickness_mm"});
  expectError(errorOf(good + "subfoov: quadrant\n"), {"subfoov: unknown key"});
  expectError(errorOf(replaced("shape: circle", "shape: circle, rotation_deg: 3")),
              {"mask.apertures[0].rotation_deg: unknown key"});
  // So is a --set path nobody reads (a typo would otherwise render as if nothing were said).
  expectError(errorOf(good, {"optics.wavelenghts_um=0.5"}), {"optics.wavelenghts_um: unknown key", "wavelengths_um"});
  expectError(errorOf(good, {"anomalies.stray_light.probabilty=0.5"}),
              {"anomalies.stray_light.probabilty: unknown key"});
}

TEST(SensorConfig, MissingFileIsNamed) {
  try {
    loadSensorConfig("/nonexistent/sensor.yaml");
    FAIL() << "expected ConfigError";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/sensor.yaml"), std::string::npos);
  }
}

// What a config may ask to allocate is bounded, each limit refused by name
// before anything is built (limits.h).
TEST(SensorConfig, ResourceLimitsAreRefusedByName) {
  auto expectError = [](const std::string& message, const std::vector<std::string>& needles) {
    ASSERT_FALSE(message.empty()) << "expected an error";
    for (const auto& n : needles) EXPECT_NE(message.find(n), std::string::npos) << message << " lacks " << n;
  };
  const std::string good = readFile(shipped("thesis_sa"));
  const std::string one = "    - {x_um: 0.0, y_um: 0.0, shape: circle, diameter_um: 100.0}\n";
  std::string many;
  for (int i = 0; i < 5000; ++i) many += one;
  std::string too_many_apertures = good;
  too_many_apertures.insert(too_many_apertures.find(one), many);
  expectError(errorOf(too_many_apertures), {"mask.apertures", "5001 apertures, over the limit of 4096"});

  // A "billion laughs" document: 9 levels of 10 aliases each.
  std::string bomb = "a0: &a0 [x, x, x, x, x, x, x, x, x, x]\n";
  for (int level = 1; level < 10; ++level) {
    const std::string prev = "*a" + std::to_string(level - 1);
    bomb += "a" + std::to_string(level) + ": &a" + std::to_string(level) + " [" + prev;
    for (int k = 1; k < 10; ++k) bomb += ", " + prev;
    bomb += "]\n";
  }
  expectError(errorOf(bomb), {"bad.yaml", "more than 1000000 YAML nodes"});
  expectError(errorOf(good, {"name=" + bomb.substr(0, 60) + "}"}), {"override"});

  expectError(errorOf(good, {"optics.psf_node_step_deg=0.001"}),
              {"optics.psf_node_step_deg", "diffraction nodes", "over the limit of 20000"});
  expectError(errorOf(good, {"anomalies.hot_pixels.count=300000"}), {"anomalies.hot_pixels.count"});
  expectError(errorOf(good, {"detector.width_px=100000"}), {"detector.width_px", "(limit)"});
  expectError(errorOf(good, {"optics.grid_size=8192"}), {"optics.grid_size", "(limit)"});

  // A file over the YAML size limit is refused before it is read (sparse file).
  const std::string big = ::testing::TempDir() + "dss_big_config.yaml";
  { std::ofstream(big) << good; }
  ASSERT_EQ(::truncate(big.c_str(), 17 << 20), 0);
  try {
    loadSensorConfig(big);
    ADD_FAILURE() << "a 17 MiB config loaded";
  } catch (const ConfigError& e) {
    expectError(e.what(), {big, "over the limit of 16.0 MiB"});
  }
  std::remove(big.c_str());
}

}  // namespace
}  // namespace dss
