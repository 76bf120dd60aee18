#!/usr/bin/env bash
# README's hot-pixel table ("Hot pixels"): per shipped sensor, one bag of 400
# images from 4 drawn sensors with 3000 hot pixels each (seed 901), the shipped
# SSCNN (calibration_node's screens) and centroid calibration evaluated by
# `dss eval` on it without and with the spike repair. Prints markdown rows.
#   scripts/hot_pixel_table.sh [SENSOR...]   (default: all four; bags in .ws/models_data, reused)
set -euo pipefail
source "$(dirname "$0")/dss_env.sh"
DATA="${DATA_DIR:-$WS/models_data}"
mkdir -p "$DATA"
scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT
[ $# -gt 0 ] || set -- wide_ma thesis_sa_t50 thesis_sa thesis_ma
echo "| sensor | SSCNN mean α / β (deg): off → on | baseline: off → on |"
echo "|---|---|---|"
for sensor in "$@"; do
  bag="$DATA/hot3000_$sensor.bag"
  [ -f "$bag" ] || "$DSS" generate --sensor "$ROOT/config/sensors/$sensor.yaml" --count 400 --seed 901 --instances 4 \
    --set anomalies.hot_pixels.count=3000 --out "$bag" 2>/dev/null
  # The baseline's repair is a setting of its calibration file.
  sed 's/^\( *\)spike_sigmas: .*/\1spike_sigmas: 0/' "$ROOT/models/$sensor.calib.yaml" > "$scratch/off.calib.yaml"
  grep -q "spike_sigmas: 0" "$scratch/off.calib.yaml" ||
    sed -i 's/^\( *\)electrons_per_dn: \(.*\)/\1electrons_per_dn: \2\n\1spike_sigmas: 0/' "$scratch/off.calib.yaml"
  evaluate() { "$DSS" eval --data "$bag" --crlb-samples 0 "$@" 2>/dev/null; }
  /usr/bin/python3 - "$sensor" \
    "$(evaluate --estimator "sscnn:$ROOT/models/$sensor.dssmodel" --screen --spike-sigmas 0)" \
    "$(evaluate --estimator "sscnn:$ROOT/models/$sensor.dssmodel" --screen)" \
    "$(evaluate --estimator "centroid:$scratch/off.calib.yaml")" \
    "$(evaluate --estimator "centroid:$ROOT/models/$sensor.calib.yaml")" <<'PY'
import json, sys
name, runs = sys.argv[1], [json.loads(x) for x in sys.argv[2:]]
def mean(e):
    return "%.5f / %.5f" % (e["alpha_mean_deg"], e["beta_mean_deg"])
print("| `%s` | %s → %s | %s → %s |" % (name, mean(runs[0]), mean(runs[1]), mean(runs[2]), mean(runs[3])))
PY
done
