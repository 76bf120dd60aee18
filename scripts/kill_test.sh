#!/usr/bin/env bash
# Crash safety under kill -9 (docs/hardening.md): kills `dss train`,
# `dss generate` and `dss report` at random points, N times each, and checks
# after every kill that no output path holds a half-written file, and that the
# next run resumes (train: from the last checkpoint) or says why it starts
# over. Prints one JSON line per command and exits 1 on any failure.
#   scripts/kill_test.sh [N]      default N = 20
set -uo pipefail
source "$(dirname "$0")/dss_env.sh"
N="${1:-20}"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
RANDOM=42
sensor=(--sensor "$ROOT/config/sensors/thesis_sa.yaml" --set optics.psf_node_step_deg=3)
failures=0

# A container file (model, checkpoint) is whole: lengths and FNV-1a checksum agree.
container_ok() { /usr/bin/python3 "$ROOT/scripts/container.py" check "$1"; }
fail() { echo "kill_test: $*" >&2; failures=$((failures + 1)); }

# Kills "$@" after a random 1..MAX s; returns 0 if it was killed, 1 if it finished.
kill_randomly() {
  local max="$1" log="$2"
  shift 2
  "$@" >"$log" 2>&1 &
  local pid=$! delay
  delay="$(awk -v r="$RANDOM" -v m="$max" 'BEGIN {printf "%.2f", 1 + (m - 1) * r / 32767}')"
  sleep "$delay"
  kill -9 "$pid" 2>/dev/null
  wait "$pid" 2>/dev/null
  # 137: killed (a run that had just finished exits 0 even if the kill reached its zombie).
  [[ $? == 137 ]]
}

# Seconds "$@" takes uninterrupted (kills are spread up to 1.1 times that).
timed() {
  local t0
  t0="$(date +%s.%N)"
  "$@" >/dev/null 2>&1 || fail "uninterrupted run failed: $*"
  awk -v a="$t0" -v b="$(date +%s.%N)" 'BEGIN {printf "%.1f", 1.1 * (b - a)}'
}

# ---- dss generate: the bag at --out is complete or absent after every kill.
max_s="$(timed "$DSS" generate "${sensor[@]}" --count 300 --seed 11 --out "$work/reference.bag")"
kills=0 restarts_noted=0 runs=0
for ((runs = 0; kills < N && runs < 2 * N; ++runs)); do
  if kill_randomly "$max_s" "$work/generate.log" "$DSS" generate "${sensor[@]}" --count 300 --seed 11 --out "$work/gen.bag"; then
    kills=$((kills + 1))
    [[ -e "$work/gen.bag" ]] && fail "generate: killed run left $work/gen.bag"
  fi
  grep -q "left from an interrupted run" "$work/generate.log" && restarts_noted=$((restarts_noted + 1))
  rm -f "$work/gen.bag"
done
"$DSS" generate "${sensor[@]}" --count 300 --seed 11 --out "$work/gen.bag" >"$work/generate.log" 2>&1 ||
  fail "generate: the run after the kills failed"
cmp -s "$work/gen.bag" "$work/reference.bag" || fail "generate: the bag after the kills differs from an uninterrupted one"
echo "{\"command\": \"generate\", \"kill_within_s\": $max_s, \"runs\": $runs, \"killed\": $kills, \"restarts_that_said_why\": $restarts_noted," \
  "\"final_bag_identical\": $(cmp -s "$work/gen.bag" "$work/reference.bag" && echo true || echo false)}"

# ---- dss train: every kill resumes from the last checkpoint; files whole or absent.
train=("$DSS" train --data "$work/reference.bag" --out "$work/model.dssmodel" --arch resnet10_w16 --epochs 200
  --batch 8 --val-fraction 0.1 --checkpoint-minutes 0.02 --patience 0 --seed 3)
kills=0 resumed=0 started_over=0 refused=0
for ((i = 0; i < N; ++i)); do
  args=("${train[@]}")
  if [[ -e "$work/model.dssmodel.ckpt" ]]; then args+=(--resume "$work/model.dssmodel.ckpt"); fi
  if kill_randomly 12 "$work/train.log" "${args[@]}"; then kills=$((kills + 1)); else break; fi
  if grep -q "resumed from" "$work/train.log"; then
    resumed=$((resumed + 1))
  elif grep -q -i "checkpoint" "$work/train.log" && grep -q -i "error\|refus\|cannot" "$work/train.log"; then
    refused=$((refused + 1))
    tail -n 2 "$work/train.log" >&2
  else
    started_over=$((started_over + 1))
  fi
  for f in "$work/model.dssmodel" "$work/model.dssmodel.ckpt"; do
    [[ -e "$f" ]] && ! container_ok "$f" && fail "train: kill $i left a damaged $f"
  done
done
args=("${train[@]}")
[[ -e "$work/model.dssmodel.ckpt" ]] && args+=(--resume "$work/model.dssmodel.ckpt")
"${args[@]}" >"$work/train.log" 2>&1 || { tail -n 5 "$work/train.log" >&2; fail "train: the run after the kills failed"; }
container_ok "$work/model.dssmodel" || fail "train: the final model is damaged"
echo "{\"command\": \"train\", \"runs\": $((i + 1)), \"killed\": $kills, \"resumed_from_checkpoint\": $resumed," \
  "\"started_without_checkpoint\": $started_over, \"checkpoint_refused\": $refused," \
  "\"final_model_whole\": $(container_ok "$work/model.dssmodel" && echo true || echo false)}"

# ---- dss report: the report directory is complete (or absent) after every kill.
"$DSS" calibrate --data "$work/reference.bag" --out "$work/calib.yaml" >/dev/null 2>&1
report=("$DSS" report --model "$work/model.dssmodel" --calibration "$work/calib.yaml" "${sensor[@]}"
  --out "$work/report" --test-images 40 --sweep-images 5 --sweep-sensors 1)
max_s="$(timed "${report[@]}")"  # a complete report is in place before the kills
kills=0
for ((runs = 0, i = 0; kills < N && runs < 2 * N; ++runs, ++i)); do
  if kill_randomly "$max_s" "$work/report.log" "${report[@]}"; then kills=$((kills + 1)); fi
  if [[ -e "$work/report" ]]; then
    [[ -s "$work/report/index.html" && -s "$work/report/summary.json" ]] || fail "report: kill $i left an incomplete report"
  elif [[ ! -e "$work/report.old" ]]; then
    fail "report: kill $i left neither the report nor the previous one"
  fi
done
"${report[@]}" >"$work/report.log" 2>&1 || { tail -n 5 "$work/report.log" >&2; fail "report: the run after the kills failed"; }
echo "{\"command\": \"report\", \"kill_within_s\": $max_s, \"runs\": $runs, \"killed\": $kills," \
  "\"final_report_complete\": $([[ -s "$work/report/index.html" ]] && echo true || echo false)}"
echo "kill_test: $failures failures" >&2
((failures == 0))
