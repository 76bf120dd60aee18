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
#   scripts/soak.sh [CASE ...]     CASE = SECONDS@RATE[/malformed]; default: 600@100 60@1000 60@100/malformed
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
WS="${DSS_WS:-$ROOT/.ws}"
export PATH="/usr/bin:$PATH"
set +u
# shellcheck disable=SC1091
source "$WS/devel/setup.bash"
set -u
export ROS_HOME="${ROS_HOME:-$WS/ros_home}"
cases=("$@")
if ((${#cases[@]} == 0)); then cases=(600@100 60@1000 60@100/malformed); fi
out="$(mktemp -d)"
trap 'rm -rf "$out"' EXIT
status=0
for c in "${cases[@]}"; do
  spec="${c%/malformed}"
  seconds="${spec%@*}" rate="${spec#*@}"
  fraction=0 tail=0
  if [[ "$c" == */malformed ]]; then fraction=0.2 tail=10; fi
  result="$out/$seconds-$rate-$fraction"
  if ! roslaunch digital_sun_sensor bench_pipeline.launch rate:="$rate" duration:="$seconds" use_nodelets:=false \
      malformed_fraction:="$fraction" clean_tail:="$tail" output:="$result.json" >"$result.log" 2>&1 ||
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
if "has died" in open(log).read() or "process has died" in open(log).read():
    problems.append("a node died")
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
