// Why an estimate is not valid: one short code per reason, optionally followed
// by ": " and a detail for people ("bad_image: 256x256, the sensor is
// 512x512"). The same codes are the STATUS_* constants of the SunAngles
// message (a test holds the two lists equal); every producer writes them
// through these names and every consumer reads the code with statusCode().
#pragma once

#include <string>

namespace dss {
namespace status {

constexpr const char* kNoSun = "no_sun";                           // no lit pixel
constexpr const char* kSaturated = "saturated";                    // too many pixels at full scale
constexpr const char* kOutOfDistribution = "out_of_distribution";  // σ too large, or unlike the training images
constexpr const char* kAmbiguousAperture = "ambiguous_aperture";   // the spots fit two apertures about equally
constexpr const char* kOutsideFov = "outside_fov";                 // beyond the field of view
constexpr const char* kNotFinite = "not_finite";                   // the estimator gave NaN or infinity
constexpr const char* kSunBehindSensor = "sun_behind_sensor";      // truth only
constexpr const char* kBadImage = "bad_image";                     // encoding, size or buffer unlike the sensor's
constexpr const char* kNoMatch = "no_match";                       // baseline: no aperture explains the spots
constexpr const char* kInconsistentSpots = "inconsistent_spots";   // baseline: the spots disagree
constexpr const char* kSpotAtEdge = "spot_at_edge";                // baseline: the spot is cut by the detector edge
constexpr const char* kEstimatorError = "estimator_error";         // the estimator threw
constexpr const char* kNoEstimator = "no_estimator";               // neither model nor calibration loaded
constexpr const char* kModelMismatch = "model_mismatch";  // the spots do not fit the model's geometry (another unit)

// Every code, for tests and documentation.
constexpr const char* kAll[] = {
    kNoSun,    kSaturated, kOutOfDistribution, kAmbiguousAperture, kOutsideFov,     kNotFinite,   kSunBehindSensor,
    kBadImage, kNoMatch,   kInconsistentSpots, kSpotAtEdge,        kEstimatorError, kNoEstimator, kModelMismatch};

// "code: detail".
inline std::string withDetail(const char* code, const std::string& detail) { return std::string(code) + ": " + detail; }

// The code of a status (the text before the first ':'; the whole text without one).
inline std::string statusCode(const std::string& status) { return status.substr(0, status.find(':')); }

}  // namespace status
}  // namespace dss
