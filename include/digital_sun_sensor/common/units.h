// Angle units, one definition for the whole package. Radians on every topic
// and in every computation; degrees only at the edges people read and write
// (configs, reports, logs). The two spellings keep the arithmetic each call
// site had (x * (pi / 180) and x * pi / 180 can differ in the last bit).
#pragma once

namespace dss {

constexpr double kPi = 3.14159265358979323846;
constexpr double kRadPerDeg = kPi / 180.0;  // multiply degrees by this
constexpr double kDegPerRad = 180.0 / kPi;  // multiply radians by this

constexpr double degToRad(double deg) { return deg * kPi / 180.0; }
constexpr double radToDeg(double rad) { return rad * 180.0 / kPi; }

}  // namespace dss
