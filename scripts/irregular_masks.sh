#!/usr/bin/env bash
# README's "Your own mask" table (details: docs/results/irregular_masks.md).
#
# Each mask is drawn by `dss mask` from a fixed seed within its own detector,
# height, readout and field; it gets training images, a fresh-seed test bag,
# the baseline (`dss calibrate` on the first 1000 training images) and a model
# trained by `dss train` with its defaults (the geometric head); both are
# evaluated on the same 2000 test images, with the readout's Cramer-Rao bound.
#
#   MASKS="A B" scripts/irregular_masks.sh        those masks (default: all), then the table
#   scripts/irregular_masks.sh table              the table from what is there
# Data in $DATA_DIR (default .ws/irregular_data); every file that exists is
# reused, so a cut run continues where it stopped. TRAIN_OPTIONS (environment)
# adds options to `dss train` (default: none, the defaults).
set -euo pipefail
source "$(dirname "$0")/dss_env.sh"
MASKS="${MASKS:-A B D E F G H I}"
DATA="${DATA_DIR:-$WS/irregular_data}"
read -r -a TRAIN_OPTIONS <<<"${TRAIN_OPTIONS:-}"
mkdir -p "$DATA"
cd "$DATA"
log() { echo "[irregular_masks] $*" >&2; }
BASE="$ROOT/config/sensors/thesis_sa.yaml"

# draw MASK: the mask's config, seeds (train, test) and training-image count.
draw() {
  local m=$1 sets=() draw_opts=()
  case "$m" in
    A) sets=(detector.width_px=640 detector.height_px=512 detector.pitch_um=2.2 mask.height_mm=2.5
         detector_noise.bit_depth=10 threshold.level_fraction=0.5 fov.alpha_max_deg=8 fov.beta_max_deg=8)
       draw_opts=(--apertures 5 --seed 11) SEEDS=(9101 9102) COUNT=24000 ;;
    B) sets=(detector.pitch_um=3.45 mask.height_mm=4.0 fov.alpha_max_deg=6 fov.beta_max_deg=6)
       draw_opts=(--diameter-um 60 --apertures 12 --seed 23 --name irregular_12) SEEDS=(9201 9202) COUNT=12000 ;;
    # D: three apertures of different sizes, two whole spots everywhere.
    D) sets=(detector.width_px=640 detector.height_px=480 detector.pitch_um=3.0 mask.height_mm=3.0
         detector_noise.bit_depth=12 threshold.level_fraction=0.7 fov.alpha_max_deg=9 fov.beta_max_deg=9)
       draw_opts=(--diameter-um 110 --diameter-spread 0.3 --apertures 3 --min-whole-spots 2 --seed 41
         --name irregular_3_sized) SEEDS=(9401 9402) COUNT=12000 ;;
    # F: three apertures alike, two whole spots everywhere (D's detector and readout).
    F) sets=(detector.width_px=640 detector.height_px=480 detector.pitch_um=3.0 mask.height_mm=3.0
         detector_noise.bit_depth=12 threshold.level_fraction=0.7 fov.alpha_max_deg=9 fov.beta_max_deg=9)
       draw_opts=(--diameter-um 110 --apertures 3 --min-whole-spots 2 --seed 43 --name irregular_3)
       SEEDS=(9451 9452) COUNT=12000 ;;
    # E: eight apertures on a coarse-pitch detector, high above it.
    E) sets=(detector.width_px=752 detector.height_px=480 detector.pitch_um=6.0 mask.height_mm=6.0
         threshold.level_fraction=0.6 fov.alpha_max_deg=5 fov.beta_max_deg=5)
       draw_opts=(--diameter-um 150 --apertures 8 --seed 53 --name irregular_8) SEEDS=(9501 9502) COUNT=12000 ;;
    # G: six apertures on a fine-pitch detector (drawn after A to F were tuned).
    G) sets=(detector.width_px=800 detector.height_px=600 detector.pitch_um=2.5 mask.height_mm=3.5
         detector_noise.bit_depth=10 threshold.level_fraction=0.6 fov.alpha_max_deg=7 fov.beta_max_deg=7)
       draw_opts=(--apertures 6 --min-whole-spots 2 --seed 61) SEEDS=(9601 9602) COUNT=12000 ;;
    # H and I: drawn after the site weights and the value saturation choice were settled on A to G.
    H) sets=(detector.width_px=720 detector.height_px=540 detector.pitch_um=3.45 mask.height_mm=3.0
         detector_noise.bit_depth=8 threshold.level_fraction=0.4 fov.alpha_max_deg=10 fov.beta_max_deg=10)
       draw_opts=(--diameter-um 80 --apertures 4 --min-whole-spots 1 --seed 71 --name irregular_4)
       SEEDS=(9701 9702) COUNT=12000 ;;
    I) sets=(detector.width_px=640 detector.height_px=640 detector.pitch_um=5.0 mask.height_mm=5.0
         detector_noise.bit_depth=12 threshold.level_fraction=0.8 fov.alpha_max_deg=6 fov.beta_max_deg=6)
       draw_opts=(--diameter-um 120 --apertures 10 --seed 83 --name irregular_10) SEEDS=(9801 9802) COUNT=12000 ;;
    *) echo "irregular_masks.sh: unknown mask '$m' (A, B, D, E, F, G, H, I)" >&2; exit 2 ;;
  esac
  local s set_args=()
  for s in "${sets[@]}"; do set_args+=(--set "$s"); done
  [ -f $m.yaml ] || "$DSS" mask --sensor "$BASE" "${set_args[@]}" "${draw_opts[@]}" --out $m.yaml >$m.mask.json
}

run_mask() {
  local m=$1
  draw $m
  [ -f $m.train.bag ] || { log "$m: $COUNT training images"; "$DSS" generate --sensor $m.yaml --count $COUNT \
    --seed ${SEEDS[0]} --out $m.train.bag >/dev/null; }
  [ -f $m.test.bag ] || "$DSS" generate --sensor $m.yaml --count 2000 --seed ${SEEDS[1]} --out $m.test.bag >/dev/null
  [ -f $m.calib.yaml ] || "$DSS" calibrate --data $m.train.bag --max-images 1000 --out $m.calib.yaml >/dev/null
  if [ ! -f $m.dssmodel ]; then
    log "$m: training (log $m.train.log)"
    local start=$SECONDS
    "$DSS" train --data $m.train.bag "${TRAIN_OPTIONS[@]}" --checkpoint $m.ckpt --out $m.dssmodel >$m.train.log 2>&1
    echo $((SECONDS - start)) >$m.train_s
  fi
  # The same head as created (weights untouched; sigma and input envelope fitted on 2000 images).
  [ -f $m.created.dssmodel ] || "$DSS" train --data $m.train.bag --epochs 0 --max-images 2000 \
    --out $m.created.dssmodel >$m.created.log 2>&1
  local est
  for est in sscnn:$m.dssmodel created:$m.created.dssmodel centroid:$m.calib.yaml; do
    local name=${est%%:*} kind=${est%%:*}
    [ $kind = created ] && kind=sscnn
    [ -f $m.$name.json ] || "$DSS" eval --data $m.test.bag --estimator $kind:${est#*:} --max-images 2000 \
      --crlb-samples 200 --csv $m.$name.csv | tail -1 >$m.$name.json
  done
  log "$m done"
}

table() {
  /usr/bin/python3 - $MASKS <<'PY'
import json, os, sys
print("| mask | SSCNN mean α / β (deg) | max α / β | valid | readout CRLB ratio | within 1σ α / β | as created: mean α / β | baseline mean α / β | baseline ratio | training |")
print("|---|---|---|---|---|---|---|---|---|---|")
for m in sys.argv[1:]:
    if not (os.path.exists(m + ".sscnn.json") and os.path.exists(m + ".centroid.json")):
        print(f"| {m} | (not run) |"); continue
    s, c = (json.load(open(f"{m}.{k}.json")) for k in ("sscnn", "centroid"))
    a = json.load(open(f"{m}.created.json")) if os.path.exists(f"{m}.created.json") else None
    created = f"{a['alpha_mean_deg']:.6f} / {a['beta_mean_deg']:.6f}" if a else "(not run)"
    t = open(m + ".train_s").read().strip() if os.path.exists(m + ".train_s") else "?"
    t = f"{int(t) / 60:.1f} min" if t.isdigit() else t
    print(f"| {m} | {s['alpha_mean_deg']:.6f} / {s['beta_mean_deg']:.6f} | {s['alpha_max_deg']:.4f} / "
          f"{s['beta_max_deg']:.4f} | {100 * s['valid_rate']:.2f} % | {s['readout_crlb_ratio']:.2f} | "
          f"{100 * s['alpha_within_1sigma']:.0f} / {100 * s['beta_within_1sigma']:.0f} % | {created} | "
          f"{c['alpha_mean_deg']:.6f} / {c['beta_mean_deg']:.6f} | {c['readout_crlb_ratio']:.2f} | {t} |")
PY
}

if [ "${1:-}" != table ]; then
  for m in $MASKS; do run_mask $m; done
fi
table
