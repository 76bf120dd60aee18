#!/usr/bin/env bash
# Setup, build, every test (gtest + rostest), gated on catkin_test_results.
# Last line: "N passed, N failed".
set -uo pipefail

REPO_DIR="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export DSS_WS="${DSS_WS:-$REPO_DIR/.ws}"
export PATH="/usr/bin:$PATH"

"$REPO_DIR/scripts/setup.sh" || { echo "setup failed"; echo "0 passed, 1 failed"; exit 1; }

cd "$DSS_WS"
# shellcheck disable=SC1091
source devel/setup.bash
export ROS_HOME="${ROS_HOME:-$DSS_WS/ros_home}"
rm -rf build/test_results
/usr/bin/python3 /usr/bin/catkin_make run_tests -DPYTHON_EXECUTABLE=/usr/bin/python3 -j"$(nproc)" 2>&1 \
  | grep -E "^\[ *(RUN|OK|FAILED|PASSED) |^\[==========\]|FAILURE|Error|error:|\[ROSTEST\]|SUMMARY|^ \* RESULT|^ \* TESTS|^ \* ERRORS|^ \* FAILURES" || true

summary="$(catkin_test_results build/test_results 2>&1)"
status=$?
echo "$summary" | tail -n 5
# "Summary: T tests, E errors, F failures, S skipped"
read -r total errors failures <<<"$(echo "$summary" | sed -n 's/^Summary: \([0-9]*\) tests, \([0-9]*\) errors, \([0-9]*\) failures.*/\1 \2 \3/p')"
total=${total:-0}; errors=${errors:-0}; failures=${failures:-0}
failed=$((errors + failures))
if [[ $status -ne 0 && $failed -eq 0 ]]; then failed=1; fi
if [[ $total -eq 0 ]]; then failed=$((failed > 0 ? failed : 1)); fi
echo "$((total - errors - failures)) passed, ${failed} failed"
[[ $failed -eq 0 ]]
