#!/usr/bin/env bash
# Reproduces shipped models from their recipes (config/recipes/<model>.yaml, read
# by scripts/recipe.py): generates the recipe's training, test and sigma bags,
# trains models/<model>.dssmodel, fits its angle correction, sigma and mirror
# average on the sigma bags, evaluates it on the test bag, then calibrates the
# centroid baseline on the first 1000 images of the first training bag
# (models/<model>.calib.yaml: calibration_node's fallback) and evaluates it on
# the same test bag. Bags go to DATA_DIR (default .ws/models_data), never into git.
#   scripts/train_models.sh [MODEL...]   (default: every recipe)
#   MODELS_DIR=/tmp/repro scripts/train_models.sh MODEL   reproduce beside the shipped file
# Bags and finished models already present are reused (a shipped model in
# MODELS_DIR, default models/, is evaluated, not retrained); an interrupted
# training resumes from its checkpoint. Results: DATA_DIR/<model>.*.json.
set -euo pipefail
source "$(dirname "$0")/dss_env.sh"
source "$(dirname "$0")/train_steps.sh"
DATA="${DATA_DIR:-$WS/models_data}"
MODELS="${MODELS_DIR:-$ROOT/models}"
mkdir -p "$DATA" "$MODELS"

# make_bag MODEL NAME:COUNT:SEED:OFFSET:SAMPLING:ANOMALIES[:SET,...] -> prints the bag's path (generated if
# missing; SET: --set overrides of this bag, after the recipe's)
make_bag() {
  local model="$1" name count seed offset sampling anomalies bag_sets
  IFS=: read -r name count seed offset sampling anomalies bag_sets <<<"$2"
  local bag="$DATA/$model.$name.bag" sets=()
  for s in $SETS ${bag_sets//,/ }; do sets+=(--set "$s"); done
  [ -f "$bag" ] || "$DSS" generate --sensor "$ROOT/config/sensors/$SENSOR.yaml" "${sets[@]}" --count "$count" \
    --seed "$seed" --offset "$offset" --sampling "$sampling" --anomalies "$anomalies" --out "$bag" >&2
  echo "$bag"
}

models=("$@")
if ((${#models[@]} == 0)); then
  for r in "$ROOT"/config/recipes/*.yaml; do models+=("$(basename "$r" .yaml)"); done
fi
for model in "${models[@]}"; do
  recipe="$ROOT/config/recipes/$model.yaml"
  [ -f "$recipe" ] || { echo "no recipe $recipe" >&2; exit 2; }
  vars="$(/usr/bin/python3 "$ROOT/scripts/recipe.py" "$recipe")"  # exits here on a bad recipe
  eval "$vars"
  train="" sigma=""
  for b in $TRAIN_BAGS; do train="$train $(make_bag "$model" "$b")"; done
  for b in $SIGMA_BAGS; do sigma="$sigma $(make_bag "$model" "$b")"; done
  test="$(make_bag "$model" "$TEST_BAG")"
  nominal=""
  for n in $NOMINAL_BAGS; do nominal="$nominal $DATA/$model.$n.bag"; done
  NOMINAL_BAGS="${nominal# }"
  heights=""
  for h in $HEIGHT_BAGS; do heights="$heights ${h%%=*}=$(make_bag "$model" "${h#*=}")"; done
  HEIGHT_BAGS="${heights# }"
  phase=()
  [ -n "$LATTICE_PHASE" ] && phase=(--lattice-phase "$LATTICE_PHASE")
  [ -n "$HEAD" ] && phase+=(--head "$HEAD")
  [ -n "$VALUE_SATURATION" ] && phase+=(--value-saturation "$VALUE_SATURATION")
  [ -n "$SPOT_READOUT" ] && phase+=(--spot-readout "$SPOT_READOUT")
  train_and_evaluate "$model" "${train# }" "$test" "${sigma# }" "$EPOCHS" "$ARCH" "$CORRECTION" "$SYMMETRY" \
    --centroid-weighting "$WEIGHTING" --feature-corrections "$FEATURES" "${phase[@]}" --lr "$LR" --seed "$TRAIN_SEED"
done
