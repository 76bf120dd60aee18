#!/usr/bin/env bash
# The published protocol (DESIGN.md section 2) on thesis_sa: far-field optics of
# the pinhole only (no solar disk, no vignetting), spot centres on the integer
# pixels of the 513 x 513 grid in a seeded shuffle; training and test images
# are disjoint grid positions (--offset). Trains models/thesis_sa_published.dssmodel
# and evaluates it beside a centroid baseline calibrated on the same protocol
# (models/thesis_sa_published.calib.yaml; both appear in dss report),
# so that both numbers stand beside the published table on the same work.
#   scripts/train_published.sh     (bags in DATA_DIR, default .ws/models_data)
set -euo pipefail
source "$(dirname "$0")/dss_env.sh"
DATA="${DATA_DIR:-$WS/models_data}"
mkdir -p "$DATA"
PROTOCOL=(--sensor "$ROOT/config/sensors/thesis_sa.yaml" --sampling grid --seed 531
  --set optics.mode=far_field --set optics.sun_disk.enabled=false --set optics.vignetting=false)
train="$DATA/published.train.bag" test="$DATA/published.test.bag" sigma="$DATA/published.sigma.bag"
model="$ROOT/models/thesis_sa_published.dssmodel" ckpt="$DATA/published.ckpt"
calib="$ROOT/models/thesis_sa_published.calib.yaml"
[ -f "$train" ] || "$DSS" generate "${PROTOCOL[@]}" --count 30000 --out "$train"
[ -f "$test" ] || "$DSS" generate "${PROTOCOL[@]}" --count 10000 --offset 30000 --out "$test"
[ -f "$sigma" ] || "$DSS" generate "${PROTOCOL[@]}" --count 5000 --offset 40000 --out "$sigma"
if [ ! -f "$model" ]; then
  resume=()
  [ -f "$ckpt" ] && resume=(--resume "$ckpt")
  "$DSS" train --data "$train" --out "$model" --checkpoint "$ckpt" --arch resnet10_w16 --epochs 30 --lr 5e-4 \
    --seed 1 "${resume[@]}" | tee "$DATA/published.train.json"
  "$DSS" calibrate-sigma --model "$model" --data "$sigma" --out "$model" | tee "$DATA/published.sigma.json"
fi
"$DSS" eval --data "$test" --estimator "sscnn:$model" --csv "$DATA/published.sscnn.csv" | tee "$DATA/published.sscnn.json"
"$DSS" calibrate --data "$train" --max-images 1000 --out "$calib" > "$DATA/published.calibrate.json"
"$DSS" eval --data "$test" --estimator "centroid:$calib" --csv "$DATA/published.centroid.csv" \
  | tee "$DATA/published.centroid.json"
