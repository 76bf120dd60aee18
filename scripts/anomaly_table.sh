#!/usr/bin/env bash
# README's per-anomaly comparison: the shipped SSCNN and the shipped centroid
# calibration of a sensor on one test bag per anomaly type (2000 images each,
# 20 sensors drawn from the config, fresh seeds), both evaluated by `dss eval`
# on the same bag with calibration_node's screens (--screen), and compared on the
# images both answer (per-image CSVs beside the bags). Prints one markdown row per
# anomaly type. A sensor without a shipped centroid calibration (thesis_ca,
# whose spots merge) is compared with its whole-pattern estimator instead.
#   scripts/anomaly_table.sh [SENSOR [TYPE...]]   (default: thesis_sa, every type; bags in .ws/models_data,
#   reused; TYPE: stray_light ghost debris hot_pixels as_built mix, each always with its own seed;
#   COUNT: images per bag, default 2000)
set -euo pipefail
source "$(dirname "$0")/dss_env.sh"
DATA="${DATA_DIR:-$WS/models_data}"
sensor="${1:-thesis_sa}"
shift || true
types=" ${*:-stray_light ghost debris hot_pixels as_built mix} "
COUNT="${COUNT:-2000}"
mkdir -p "$DATA"
baseline="centroid:$ROOT/models/$sensor.calib.yaml" kind=centroid
[ -f "$ROOT/models/$sensor.calib.yaml" ] || baseline="pattern:$ROOT/config/sensors/$sensor.yaml" kind=pattern
echo "| anomaly | SSCNN mean α / β (deg) | max α / β | valid | $kind mean α / β (deg) | max α / β | valid | on the images both answer: SSCNN / $kind mean α / β (deg) |"
echo "|---|---|---|---|---|---|---|---|"
seed=600
for spec in stray_light=1 ghost=1 debris=1 hot_pixels=30 as_built=1 mix; do
  seed=$((seed + 1))
  name="${spec%%=*}" bag="$DATA/anom_${spec%%=*}.bag"
  [[ "$types" == *" $name "* ]] || continue
  [ "$sensor" = thesis_sa ] || bag="$DATA/anom_${sensor}_${spec%%=*}.bag"
  [ "$COUNT" = 2000 ] || bag="${bag%.bag}_$COUNT.bag"
  [ -f "$bag" ] || "$DSS" generate --sensor "$ROOT/config/sensors/$sensor.yaml" --anomalies "$spec" --instances 20 \
    --count "$COUNT" --seed "$seed" --out "$bag"  # its progress on stderr: thesis_ca's units take a minute an image
  sscnn=$("$DSS" eval --data "$bag" --estimator "sscnn:$ROOT/models/$sensor.dssmodel" --screen --crlb-samples 0 \
    --csv "$bag.sscnn.csv" 2>/dev/null)
  centroid=$("$DSS" eval --data "$bag" --estimator "$baseline" --screen --crlb-samples 0 --csv "$bag.$kind.csv" 2>/dev/null)
  /usr/bin/python3 - "$name ($spec)" "$sscnn" "$centroid" "$bag.sscnn.csv" "$bag.$kind.csv" <<'PY'
import csv, json, sys
name, s, c = sys.argv[1], json.loads(sys.argv[2]), json.loads(sys.argv[3])
def cells(e):
    if e["alpha_mean_deg"] is None:  # nothing answered
        return "— | — | %.1f %%" % (100 * e["valid_rate"])
    return "%.5f / %.5f | %.4f / %.4f | %.1f %%" % (e["alpha_mean_deg"], e["beta_mean_deg"], e["alpha_max_deg"],
                                                  e["beta_max_deg"], 100 * e["valid_rate"])
# Each estimator's mean is over the images it marked valid; the baseline declines some hard ones
# (spot_at_edge), so the like-for-like comparison is on the images both answer.
rows = [{r["index"]: r for r in csv.DictReader(open(f))} for f in sys.argv[4:6]]
both = [k for k in rows[0] if rows[0][k]["valid"] == "1" and rows[1].get(k, {}).get("valid") == "1"]
def mean(r, axis):
    return sum(abs(float(r[k][axis + "_error_deg"])) for k in both) / max(1, len(both))
common = "%.6f / %.6f, %.6f / %.6f (%d)" % (mean(rows[0], "alpha"), mean(rows[0], "beta"), mean(rows[1], "alpha"),
                                           mean(rows[1], "beta"), len(both)) if both else "— (0)"
print("| %s | %s | %s | %s |" % (name, cells(s), cells(c), common))
PY
done
