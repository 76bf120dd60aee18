# Sourced by the scripts that drive the dss command line: ROOT (the package),
# WS (the catkin workspace: $DSS_WS, default .ws), DSS (the built dss binary,
# or $DSS), and a clear stop when it is not built.
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
WS="${DSS_WS:-$ROOT/.ws}"
DSS="${DSS:-$WS/devel/lib/digital_sun_sensor/dss}"
[ -x "$DSS" ] || { echo "dss not built: run scripts/setup.sh" >&2; exit 1; }
