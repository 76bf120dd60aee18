#!/usr/bin/env bash
# Reproduces the shipped models in models/ and README's accuracy table: for each
# sensor, a training bag and a fresh-seed test bag (continuous random angles over
# the whole field of view), `dss train`, `dss calibrate-sigma` on a third fresh
# bag, then `dss eval` of the model and of the centroid baseline (calibrated on
# the first 1000 training images, shipped as models/<sensor>.calib.yaml:
# calibration_node's fallback) on the same test bag. Bags go to DATA_DIR (default .ws/models_data), never into git.
#   scripts/train_models.sh [SENSOR...]     (default: thesis_sa thesis_ma wide_ma thesis_sa_t50)
# Bags and finished models already present are reused; an interrupted training
# resumes from its checkpoint. Results: DATA_DIR/<sensor>.*.json.
set -euo pipefail
source "$(dirname "$0")/dss_env.sh"
source "$(dirname "$0")/train_steps.sh"
DATA="${DATA_DIR:-$WS/models_data}"
mkdir -p "$DATA" "$ROOT/models"

# sensor, training images, training seed, test seed, epochs, architecture, sigma-calibration seed,
# centroid weighting, feature corrections (on: angle corrections from the pooled features; off: the angles a
# smooth function of the spot position), angle correction (maximum degree fitted on the sigma bag; keep: none fitted),
# inference symmetry (dihedral: estimates averaged over the 8 mirror images; keep: none),
# anomaly bags added to the training and sigma bags (none, or ANOMALIES:TRAIN_COUNT:TRAIN_SEED:SIGMA_COUNT:SIGMA_SEED,
# ANOMALIES as for dss generate --anomalies), nominal images from the field's outer band added to the training
# (none, or COUNT:SEED: dss generate --sampling edge, where the detector edge cuts the spot)
recipe() {
  case "$1" in
    thesis_sa) echo "60000 501 502 30 resnet18_w32 503 learned on keep dihedral stray_light=1:20000:571:1500:573 12000:581" ;;
    thesis_ma) echo "60000 511 512 20 resnet10_w16 513 learned on keep dihedral stray_light=1:20000:561:1500:563 none" ;;
    wide_ma) echo "24000 521 522 5 resnet10_w16 523 intensity off 16 keep stray_light=1:4000:591:1500:593 none" ;;
    thesis_sa_t50) echo "40000 541 542 36 resnet10_w16 543 learned on keep dihedral none none" ;;
    *) echo "unknown sensor '$1'" >&2; exit 2 ;;
  esac
}

for sensor in "${@:-thesis_sa thesis_ma wide_ma thesis_sa_t50}"; do
  for s in $sensor; do
    read -r count train_seed test_seed epochs arch sigma_seed weighting features correction symmetry anomaly edge \
      <<<"$(recipe "$s")"
    cfg="$ROOT/config/sensors/$s.yaml" train="$DATA/$s.train.bag" test="$DATA/$s.test.bag"
    sigma="$DATA/$s.sigma.bag"
    [ -f "$train" ] || "$DSS" generate --sensor "$cfg" --count "$count" --seed "$train_seed" --out "$train"
    [ -f "$test" ] || "$DSS" generate --sensor "$cfg" --count 10000 --seed "$test_seed" --out "$test"
    [ -f "$sigma" ] || "$DSS" generate --sensor "$cfg" --count 5000 --seed "$sigma_seed" --out "$sigma"
    if [ "$anomaly" != none ]; then
      IFS=: read -r spec anomaly_count anomaly_seed anomaly_sigma_count anomaly_sigma_seed <<<"$anomaly"
      extra="$DATA/$s.${spec%%=*}.train.bag" extra_sigma="$DATA/$s.${spec%%=*}.sigma.bag"
      [ -f "$extra" ] || "$DSS" generate --sensor "$cfg" --anomalies "$spec" --count "$anomaly_count" \
        --seed "$anomaly_seed" --out "$extra"
      [ -f "$extra_sigma" ] || "$DSS" generate --sensor "$cfg" --anomalies "$spec" --count "$anomaly_sigma_count" \
        --seed "$anomaly_sigma_seed" --out "$extra_sigma"
      train="$train $extra" sigma="$sigma $extra_sigma"
    fi
    if [ "$edge" != none ]; then
      IFS=: read -r edge_count edge_seed <<<"$edge"
      extra="$DATA/$s.edge.train.bag"
      [ -f "$extra" ] || "$DSS" generate --sensor "$cfg" --sampling edge --count "$edge_count" --seed "$edge_seed" \
        --out "$extra"
      train="$train $extra"
    fi
    train_and_evaluate "$s" "$train" "$test" "$sigma" "$epochs" "$arch" "$correction" "$symmetry" \
      --centroid-weighting "$weighting" --feature-corrections "$features"
  done
done
