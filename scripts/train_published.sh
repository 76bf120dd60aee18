#!/usr/bin/env bash
# The published protocol (DESIGN.md section 2) on thesis_sa or thesis_ma: far-field
# optics of the pinholes only (no solar disk, no vignetting), spot centres on the
# integer pixels of the 513 x 513 grid in a seeded shuffle; training and test
# images are disjoint grid positions (--offset). Trains
# models/<sensor>_published.dssmodel and evaluates it beside a centroid baseline
# calibrated on the same protocol (models/<sensor>_published.calib.yaml; both
# appear in dss report), so that both numbers stand beside the published table
# on the same work.
#   scripts/train_published.sh [SENSOR...]   (default: thesis_sa thesis_ma; bags in DATA_DIR, default .ws/models_data)
# Bags and finished models already present are reused; an interrupted training
# resumes from its checkpoint.
set -euo pipefail
source "$(dirname "$0")/dss_env.sh"
source "$(dirname "$0")/train_steps.sh"
DATA="${DATA_DIR:-$WS/models_data}"
mkdir -p "$DATA"

# sensor -> training epochs (the grid seed 531 and offsets are dss report's defaults)
epochs_for() {
  case "$1" in
    thesis_sa) echo 30 ;;
    thesis_ma) echo 30 ;;
    *) echo "no published protocol for sensor '$1' (expected thesis_sa or thesis_ma)" >&2; exit 2 ;;
  esac
}

for sensor in "${@:-thesis_sa thesis_ma}"; do
  for s in $sensor; do
    epochs="$(epochs_for "$s")"
    protocol=(--sensor "$ROOT/config/sensors/$s.yaml" --sampling grid --seed 531
      --set optics.mode=far_field --set optics.sun_disk.enabled=false --set optics.vignetting=false)
    name="${s}_published"
    train="$DATA/$name.train.bag" test="$DATA/$name.test.bag" sigma="$DATA/$name.sigma.bag"
    [ -f "$train" ] || "$DSS" generate "${protocol[@]}" --count 30000 --out "$train"
    [ -f "$test" ] || "$DSS" generate "${protocol[@]}" --count 10000 --offset 30000 --out "$test"
    [ -f "$sigma" ] || "$DSS" generate "${protocol[@]}" --count 5000 --offset 40000 --out "$sigma"
    train_and_evaluate "$name" "$train" "$test" "$sigma" "$epochs" resnet10_w16 keep dihedral
  done
done
