// What the package accepts from outside, in one place. Every input is checked
// against these before anything is allocated for it, and refused with an
// error that names the limit, so that a hostile or broken file, message or
// config ends in a clear message instead of std::bad_alloc or an OOM kill.
// The values leave room well beyond any real sun sensor (the shipped ones are
// at most 2048 x 2048 px with 117 apertures) while keeping one input well
// under the 24 GiB of the machines the package is built for.
#pragma once

#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <string>

namespace dss {
namespace limits {

// An input over one of the limits below (where no more specific error type
// of the input's reader applies).
class LimitExceeded : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Detector and image size (sensor configs, image messages).
constexpr int kMaxDetectorSidePx = 8192;
constexpr std::uint64_t kMaxImageBytes = 256ull << 20;  // one image message's data

// Mask and optics (sensor configs).
constexpr std::size_t kMaxApertures = 4096;
constexpr int kMaxDiffractionGrid = 4096;  // FFT grid side
constexpr int kMaxWavelengths = 64;
// Diffraction patterns the simulator may cache per aperture shape over the
// field of view ((2 alpha_max / psf_node_step_deg + 1) x (same for beta)):
// each is a grid_size^2 map, so this bounds the spot cache of a long run.
constexpr std::uint64_t kMaxPsfNodes = 20'000;

// Sparse network input: lit sites of one image. A whole lit 2048 x 2048
// detector is 4.2 M sites; a sun image has a few thousand (thesis_ca: ~30 000).
constexpr std::size_t kMaxSitesPerImage = 1u << 20;

// Network shape a model file may declare (the shipped presets are at most 4
// stages of 3-6 blocks, 256 channels wide): the network is built before its
// weights are read, so these bound what a damaged model file can allocate.
constexpr int kMaxStages = 8;
constexpr int kMaxBlocksPerStage = 16;
constexpr int kMaxLayerWidth = 1024;
constexpr int kMaxStemKernel = 15;
constexpr int kMaxLatticeSide = 256;  // lattice head columns and rows

// Files read whole into memory.
constexpr std::uint64_t kMaxYamlFileBytes = 16ull << 20;       // sensor configs, calibrations
constexpr std::uint64_t kMaxModelFileBytes = 1ull << 30;       // model files
constexpr std::uint64_t kMaxCheckpointFileBytes = 4ull << 30;  // model + best model + optimizer state
// Parsed YAML nodes, aliases counted at their expanded size (an alias bomb
// expands to billions of nodes from a few hundred bytes).
constexpr std::uint64_t kMaxYamlNodes = 1'000'000;

// Images held in memory from bags (training sets, calibration sets).
constexpr std::uint64_t kMaxTrainingSetBytes = 12ull << 30;

// "1.0 GiB", "16 MiB", "4096": limits as people read them in errors.
std::string describeBytes(std::uint64_t bytes);

}  // namespace limits
}  // namespace dss
