#!/usr/bin/env bash
# Reproduces README's centroid-baseline tables: for each shipped sensor, nominal
# and with the anomaly mix, a calibration bag and a disjoint test bag of the
# SAME simulated sensor (same seed, later sample offset), `dss calibrate`, then
# `dss eval`. Plus the published protocol on thesis_sa (far_field optics, grid).
#   scripts/baseline_tables.sh [OUT_DIR [CASE...]]   (default: .ws/baseline_tables, all cases)
# Bags already present are reused. Prints one markdown row per case and keeps
# every JSON line in OUT_DIR/results.jsonl (appended).
set -euo pipefail
source "$(dirname "$0")/dss_env.sh"
OUT="${1:-$WS/baseline_tables}"
ONLY=("${@:2}")
mkdir -p "$OUT"

# case name, sensor, sampling, seed, calibration count, test count, extra args...
run_case() {
  local name="$1" sensor="$2" sampling="$3" seed="$4" cal_count="$5" test_count="$6"
  shift 6
  if [ ${#ONLY[@]} -gt 0 ] && [[ ! " ${ONLY[*]} " == *" $name "* ]]; then return; fi
  local cal="$OUT/$name.cal.bag" test="$OUT/$name.test.bag"
  [ -f "$cal" ] || "$DSS" generate --sensor "$ROOT/config/sensors/$sensor.yaml" --sampling "$sampling" \
    --count "$cal_count" --seed "$seed" --out "$cal" "$@"
  [ -f "$test" ] || "$DSS" generate --sensor "$ROOT/config/sensors/$sensor.yaml" --sampling "$sampling" \
    --count "$test_count" --seed "$seed" --offset "$cal_count" --out "$test" "$@"
  local fit eval
  if ! fit=$("$DSS" calibrate --data "$cal" --out "$OUT/$name.calib.yaml" 2>"$OUT/$name.calibrate.log"); then
    # A sensor the centroid chain cannot calibrate gets a row saying why.
    echo "| $name | calibration failed: $(tail -n 1 "$OUT/$name.calibrate.log" | sed 's/^dss calibrate: error: //') |||||"
    echo "{\"case\": \"$name\", \"error\": \"$(tail -n 1 "$OUT/$name.calibrate.log")\"}" >> "$OUT/results.jsonl"
    return
  fi
  eval=$("$DSS" eval --data "$test" --estimator "centroid:$OUT/$name.calib.yaml" --csv "$OUT/$name.csv" \
    2>"$OUT/$name.eval.log")
  echo "{\"case\": \"$name\", \"calibrate\": $fit, \"eval\": $eval}" >> "$OUT/results.jsonl"
  /usr/bin/python3 - "$name" "$eval" <<'PY'
import json, sys
name, e = sys.argv[1], json.loads(sys.argv[2])
f = lambda v, d=4: "n/a" if v is None else f"{v:.{d}f}"
print(f"| {name} | {f(e['alpha_mean_deg'])} / {f(e['beta_mean_deg'])} | {f(e['alpha_rms_deg'])} / {f(e['beta_rms_deg'])} "
      f"| {f(e['alpha_max_deg'],3)} / {f(e['beta_max_deg'],3)} | {100*e['valid_rate']:.1f}% | {f(e['subfov_accuracy'],3)} "
      f"| {f(e['crlb_ratio'],1)} |")
PY
}

echo "| case | mean α / β (deg) | RMS α / β (deg) | max α / β (deg) | valid | sub-FOV acc. | CRLB ratio |"
echo "|---|---|---|---|---|---|---|"
for sensor in thesis_sa thesis_ma; do
  run_case "${sensor}_nominal" "$sensor" random 101 1000 2000
  run_case "${sensor}_mix" "$sensor" random 202 1000 2000 --anomalies mix
done
# Many apertures: fewer images, and the mix without aperture diameter errors,
# which would give every aperture its own diffraction cache (hours to render).
for sensor in thesis_ca wide_ma; do
  run_case "${sensor}_nominal" "$sensor" random 101 500 1000
  run_case "${sensor}_mix" "$sensor" random 202 500 1000 --anomalies mix --set as_built.aperture_diameter_sigma_um=0
done
run_case thesis_sa_published thesis_sa grid 303 1000 2000 \
  --set optics.mode=far_field --set optics.sun_disk.enabled=false --set optics.vignetting=false
