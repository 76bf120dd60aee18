#!/usr/bin/env bash
# Load benchmark of the estimator pipeline (docs/pipeline.md, "Load"): for each
# case, launch/bench_pipeline.launch publishes pre-rendered images at the rate
# and prints one JSON line (rate in/out, latency p50/p99 from image stamp to
# /sun_sensor/angles, drops, estimator memory). Cases run one after another.
#   scripts/bench_pipeline.sh [DURATION_S] [CASE...]   CASE = MODE@RATE[/none], e.g. nodelet@100, node@1000/none
#   (/none: calibration_node's ~inference_symmetry none, the image alone; default cases:
#   nodelet@100 node@100 nodelet@1000 node@1000)
set -euo pipefail
source "$(dirname "$0")/ros_env.sh"
duration="${1:-10}"
shift || true
cases=("${@:-nodelet@100 node@100 nodelet@1000 node@1000}")
out="$(mktemp -d)"
trap 'rm -rf "$out"' EXIT
for c in ${cases[*]}; do
  symmetry=model
  [[ "$c" == */none ]] && symmetry=none
  spec="${c%/none}"
  mode="${spec%@*}" rate="${spec#*@}"
  case "$mode" in nodelet) nodelets=true ;; node) nodelets=false ;; *) echo "unknown mode '$mode' in '$c'" >&2; exit 2 ;; esac
  result="$out/$mode-$rate-$symmetry"
  if ! roslaunch digital_sun_sensor bench_pipeline.launch rate:="$rate" duration:="$duration" use_nodelets:="$nodelets" \
      inference_symmetry:="$symmetry" output:="$result.json" >"$result.log" 2>&1 || [ ! -s "$result.json" ]; then
    tail -n 20 "$result.log" >&2
    echo "bench case $c failed" >&2
    exit 1
  fi
  cat "$result.json"
done
