#!/usr/bin/env bash
# Soak and load of calibration_node (docs/hardening.md): for each case,
# launch/bench_pipeline.launch runs the node as a separate process
# (use_nodelets:=false) fed by pipeline_bench, and prints one JSON line (rates,
# latency, drops, the node's resident memory start/max/end, and with
# malformed images how each was answered and what the diagnostics said).
# Ends with a verdict line per case; exits 1 if any case fails its checks:
#   the node never exits; resident memory grows < 5 % from start to end;
#   every malformed image answered valid=false with status bad_image;
#   diagnostics WARN/ERROR while malformed images come, OK after.
# Case "simulator": simulator_node at 100 Hz for 60 s while /attitude gets
# valid, NaN and non-unit quaternions at 100 Hz each: it must stay up, keep
# its image rate and grow < 5 % in resident memory.
#   scripts/soak.sh [CASE ...]     CASE = SECONDS@RATE[/malformed][/none] or simulator
#   (/none: calibration_node's ~inference_symmetry none, the image alone);
#   default: 600@100 60@1000 60@100/malformed/none simulator
set -euo pipefail
source "$(dirname "$0")/ros_env.sh"
cases=("$@")
if ((${#cases[@]} == 0)); then cases=(600@100 60@1000 60@100/malformed/none simulator); fi
out="$(mktemp -d)"
trap 'rm -rf "$out"' EXIT
status=0

rss_mib() { awk '/VmRSS/ {printf "%.1f", $2 / 1024}' "/proc/$1/status" 2>/dev/null || echo 0; }

soak_simulator() {
  local seconds=60 pids=() sim
  roscore -p 11399 >"$out/roscore.log" 2>&1 &
  pids+=($!)
  export ROS_MASTER_URI=http://localhost:11399
  sleep 3
  rosrun digital_sun_sensor simulator_node _rate_hz:=100 _warm_up_threads:=1 >"$out/sim.log" 2>&1 &
  sim=$!
  local header='header: {stamp: now, frame_id: base_link}'
  for q in "{x: 0, y: 0, z: 0, w: 1}" "{x: 0, y: 0, z: 0, w: .nan}" "{x: 0, y: 0, z: 0, w: 2}"; do
    rostopic pub -s -r 100 /attitude geometry_msgs/QuaternionStamped "{$header, quaternion: $q}" >/dev/null 2>&1 &
    pids+=($!)
  done
  # Warm-up: the diffraction cache fills before the first image.
  timeout 180 rostopic echo -n 1 /image/height >/dev/null 2>&1 || true
  sleep 5
  local start end rate alive=true
  start="$(rss_mib "$sim")"
  rate="$(timeout 15 rostopic hz -w 500 /image 2>/dev/null | grep -oP 'average rate: \K[0-9.]+' | tail -n1)"
  sleep $((seconds - 15))
  kill -0 "$sim" 2>/dev/null || alive=false
  end="$(rss_mib "$sim")"
  kill "$sim" "${pids[@]}" 2>/dev/null
  wait 2>/dev/null
  unset ROS_MASTER_URI
  /usr/bin/python3 - "$alive" "$start" "$end" "${rate:-0}" <<'PY'
import json, sys
alive, start, end, rate = sys.argv[1] == "true", float(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4])
growth = (end - start) / start if start > 0 else float("nan")
problems = [p for p, bad in (("simulator_node exited", not alive),
                             ("resident memory %.1f -> %.1f MiB" % (start, end), not growth < 0.05),
                             ("image rate %.1f Hz of 100" % rate, rate < 90)) if bad]
print(json.dumps({"case": "simulator", "seconds": 60, "attitudes_per_s": 300, "image_rate_hz": rate,
                  "rss_start_mib": start, "rss_end_mib": end, "rss_growth_percent": round(100 * growth, 2),
                  "verdict": "pass" if not problems else "fail: " + "; ".join(problems)}))
sys.exit(1 if problems else 0)
PY
}

for c in "${cases[@]}"; do
  if [[ "$c" == simulator ]]; then
    soak_simulator || status=1
    continue
  fi
  spec="${c%%/*}"
  seconds="${spec%@*}" rate="${spec#*@}"
  fraction=0 tail=0 symmetry=model
  if [[ "$c" == */malformed* ]]; then fraction=0.2 tail=10; fi
  if [[ "$c" == */none ]]; then symmetry=none; fi
  result="$out/$seconds-$rate-$fraction-$symmetry"
  if ! roslaunch digital_sun_sensor bench_pipeline.launch rate:="$rate" duration:="$seconds" use_nodelets:=false \
      malformed_fraction:="$fraction" clean_tail:="$tail" inference_symmetry:="$symmetry" output:="$result.json" \
      >"$result.log" 2>&1 ||
      [ ! -s "$result.json" ]; then
    tail -n 20 "$result.log" >&2
    echo "{\"case\": \"$c\", \"verdict\": \"fail: the bench or the node exited\"}"
    status=1
    continue
  fi
  cat "$result.json"
  if ! /usr/bin/python3 - "$c" "$result.json" "$result.log" <<'PY'; then status=1; fi
import json, sys
case, path, log = sys.argv[1:4]
r = json.load(open(path))
problems = []
import re
if re.search(r"\[sun_sensor/calibration-\d+\] process has died", open(log).read()):
    problems.append("calibration_node died")  # (the bench, a required node, "dies" when it is done)
start, end = r["estimator_rss_start_mib"], r["estimator_rss_end_mib"]
growth = (end - start) / start if start > 0 else float("nan")
if not growth < 0.05:
    problems.append("resident memory %.1f -> %.1f MiB (%+.1f %%)" % (start, end, 100 * growth))
if "malformed_published" in r:
    if r["malformed_refused_bad_image"] != r["malformed_answered"] or r["malformed_answered"] == 0:
        problems.append("malformed images: %d answered, %d refused as bad_image (%s)" % (
            r["malformed_answered"], r["malformed_refused_bad_image"], r["malformed_first_wrong_answer"]))
    if r["diagnostics_not_ok_reports"] == 0:
        problems.append("diagnostics stayed OK while malformed images came")
    if r["diagnostics_level_after"] != 0:
        problems.append("diagnostics level %s after the clean tail: %s" % (
            r["diagnostics_level_after"], r["diagnostics_message_after"]))
print(json.dumps({"case": case, "rss_growth_percent": round(100 * growth, 2),
                  "verdict": "pass" if not problems else "fail: " + "; ".join(problems)}))
sys.exit(1 if problems else 0)
PY
done
exit $status
