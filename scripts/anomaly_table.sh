#!/usr/bin/env bash
# README's per-anomaly comparison: the shipped SSCNN and the shipped centroid
# calibration of a sensor on one test bag per anomaly type (2000 images each,
# 20 sensors drawn from the config, fresh seeds), both evaluated by `dss eval`
# on the same bag with calibration_node's screens (--screen). Prints one markdown
# row per anomaly type.
#   scripts/anomaly_table.sh [SENSOR]   (default: thesis_sa; bags in .ws/models_data, reused)
set -euo pipefail
source "$(dirname "$0")/dss_env.sh"
DATA="${DATA_DIR:-$WS/models_data}"
sensor="${1:-thesis_sa}"
mkdir -p "$DATA"
echo "| anomaly | SSCNN mean α / β (deg) | max α / β | valid | centroid mean α / β (deg) | max α / β | valid |"
echo "|---|---|---|---|---|---|---|"
seed=600
for spec in stray_light=1 ghost=1 debris=1 hot_pixels=30 as_built=1 mix; do
  seed=$((seed + 1))
  name="${spec%%=*}" bag="$DATA/anom_${spec%%=*}.bag"
  [ "$sensor" = thesis_sa ] || bag="$DATA/anom_${sensor}_${spec%%=*}.bag"
  [ -f "$bag" ] || "$DSS" generate --sensor "$ROOT/config/sensors/$sensor.yaml" --anomalies "$spec" --instances 20 \
    --count 2000 --seed "$seed" --out "$bag" 2>/dev/null
  sscnn=$("$DSS" eval --data "$bag" --estimator "sscnn:$ROOT/models/$sensor.dssmodel" --screen --crlb-samples 0 2>/dev/null)
  centroid=$("$DSS" eval --data "$bag" --estimator "centroid:$ROOT/models/$sensor.calib.yaml" --screen --crlb-samples 0 2>/dev/null)
  /usr/bin/python3 - "$name ($spec)" "$sscnn" "$centroid" <<'PY'
import json, sys
name, s, c = sys.argv[1], json.loads(sys.argv[2]), json.loads(sys.argv[3])
def cells(e):
    return "%.5f / %.5f | %.4f / %.4f | %.1f %%" % (e["alpha_mean_deg"], e["beta_mean_deg"], e["alpha_max_deg"],
                                                  e["beta_max_deg"], 100 * e["valid_rate"])
print("| %s | %s | %s |" % (name, cells(s), cells(c)))
PY
done
