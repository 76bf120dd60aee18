// Hot pixels that touch a spot: the screens' small-group removal cannot see
// them (they join the spot's lit group), yet an intensity-weighted centroid
// gives them their full brightness. Light through an aperture is smooth on
// the pixel scale (spots are tens of pixels across), so a pixel brighter than
// every one of its 8 neighbours by more than the readout noise allows is a
// spike; it is replaced by the median of those neighbours. Used by both
// estimators: calibration_node's screen and the baseline's spot extraction.
#pragma once

#include <opencv2/core.hpp>
#include <vector>

#include "digital_sun_sensor/sim/sensor_config.h"

namespace dss {

// The default, chosen on hot-pixel and nominal images of every shipped sensor
// (docs/baseline.md, "Hot pixels"): 6 caught fewer hot pixels, 3 did no better than 4.
constexpr double kDefaultSpikeSigmas = 4.0;
// Diffraction peaks of wide_ma's small pinholes are sharp: a real central
// pixel reads 1.15-1.4 times its brightest neighbour (the most at low codes,
// where the noise margin is wide). This share of the neighbour's code is
// allowed on top of the noise margin.
constexpr double kSpikePeakAllowance = 0.1;

// Per output code m of the brightest neighbour, how far above m a pixel may
// read before it counts as a spike: `sigmas` standard deviations of the
// difference of two pixels at m (shot, read and PRNU noise, quantization,
// through the on-chip threshold's rescale), plus kSpikePeakAllowance x m and
// 1 DN. Empty (no filtering) when sigmas <= 0. Throws std::invalid_argument
// when sigmas is not finite.
std::vector<int> spikeMargins(const SensorConfig& sensor, double sigmas);

// `image` (CV_8U or CV_16U, one channel) with its spikes replaced; the image
// itself when it has none or `margin_dn` is empty. Neighbours beyond the
// image border are left out; codes beyond the table use its last margin.
// `repaired`, when given, receives the number of pixels replaced.
cv::Mat repairSpikes(const cv::Mat& image, const std::vector<int>& margin_dn, int* repaired = nullptr);

}  // namespace dss
