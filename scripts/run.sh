#!/usr/bin/env bash
# README's main command: installs and builds what is missing (scripts/setup.sh,
# idempotent), then runs the simulator + estimator pipeline with the shipped
# model and prints, live, the estimate beside the truth and the error.
# Arguments go to launch/pipeline.launch, e.g.
#   scripts/run.sh rate:=100 profile:=random use_nodelets:=false
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export DSS_WS="${DSS_WS:-$ROOT/.ws}"
export PATH="/usr/bin:$PATH"
echo "[run] setup + build (log: $DSS_WS/setup.log)"
mkdir -p "$DSS_WS"
if ! "$ROOT/scripts/setup.sh" >"$DSS_WS/setup.log" 2>&1; then
  tail -n 40 "$DSS_WS/setup.log"
  echo "[run] setup failed; see $DSS_WS/setup.log" >&2
  exit 1
fi
set +u
# shellcheck disable=SC1091
source "$DSS_WS/devel/setup.bash"
set -u
exec roslaunch digital_sun_sensor pipeline.launch "$@"
