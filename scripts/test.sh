#!/usr/bin/env bash
# Setup, build, every test (gtest + rostest), gated on catkin_test_results.
# Last line: "N passed, N failed".
#   scripts/test.sh          every test (what CI runs)
#   scripts/test.sh fast     the unit tests alone: no ROS master, no trained
#                            models pinned, no dss subprocesses (under 2 minutes)
set -uo pipefail

# The unit-test executables of "fast" (test/CMakeLists.txt).
FAST_TESTS=(test_core test_baseline test_nn test_fuzz_regressions)
targets=(run_tests)
if [[ "${1:-}" == fast ]]; then
  targets=()
  for t in "${FAST_TESTS[@]}"; do targets+=("run_tests_digital_sun_sensor_gtest_$t"); done
elif [[ $# -gt 0 ]]; then
  echo "usage: scripts/test.sh [fast]" >&2
  exit 2
fi

REPO_DIR="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export DSS_WS="${DSS_WS:-$REPO_DIR/.ws}"
export PATH="/usr/bin:$PATH"

mkdir -p "$DSS_WS"
echo "[test] setup + build (log: $DSS_WS/setup.log)"
if ! "$REPO_DIR/scripts/setup.sh" >"$DSS_WS/setup.log" 2>&1; then
  tail -n 40 "$DSS_WS/setup.log"
  echo "setup failed"
  echo "0 passed, 1 failed"
  exit 1
fi

cd "$DSS_WS"
set +u  # ROS's setup scripts read unset variables
# shellcheck disable=SC1091
source devel/setup.bash
set -u
export ROS_HOME="${ROS_HOME:-$DSS_WS/ros_home}"
rm -rf build/test_results
/usr/bin/python3 /usr/bin/catkin_make "${targets[@]}" -DPYTHON_EXECUTABLE=/usr/bin/python3 -j"$(nproc)" 2>&1 \
  | grep -E "^\[ *(RUN|OK|FAILED|PASSED) |^\[==========\]|FAILURE|Error|error:|\[ROSTEST\]|SUMMARY|^ \* RESULT|^ \* TESTS|^ \* ERRORS|^ \* FAILURES" || true

summary="$(catkin_test_results build/test_results 2>&1)"
status=$?
echo "$summary" | tail -n 8
# Count test cases from the result files (catkin_test_results counts gtest
# suites twice); a test case fails if it has a <failure> or <error>.
read -r passed failed <<<"$(/usr/bin/python3 - build/test_results <<'PY'
import glob, sys, xml.etree.ElementTree as ET
passed = failed = 0
for path in glob.glob(sys.argv[1] + "/**/*.xml", recursive=True):
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError:
        failed += 1
        continue
    for case in root.iter("testcase"):
        if case.find("failure") is not None or case.find("error") is not None:
            failed += 1
        else:
            passed += 1
print(passed, failed)
PY
)"
passed=${passed:-0}; failed=${failed:-0}
if [[ $status -ne 0 && $failed -eq 0 ]]; then failed=1; fi
if [[ $passed -eq 0 && $failed -eq 0 ]]; then failed=1; fi
echo "${passed} passed, ${failed} failed"
[[ $failed -eq 0 ]]
