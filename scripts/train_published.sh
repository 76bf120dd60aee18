#!/usr/bin/env bash
# The published protocol's models (recipes config/recipes/<sensor>_published.yaml):
#   scripts/train_published.sh [SENSOR...]   (default: thesis_sa thesis_ma)
set -euo pipefail
sensors=("${@:-thesis_sa thesis_ma}")
models=()
for s in ${sensors[*]}; do models+=("${s}_published"); done
exec "$(dirname "$0")/train_models.sh" "${models[@]}"
