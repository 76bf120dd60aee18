#!/usr/bin/env bash
# Fuzzes the package's inputs with libFuzzer under ASan and UBSan
# (docs/hardening.md): builds the targets of fuzz/ with clang in their own
# workspace, runs each for a set time (two at a time on two cores) from the
# seeds in fuzz/seeds plus its growing corpus, and prints one JSON line per
# target (executions, coverage, findings) and a summary.
#   scripts/fuzz.sh [SECONDS_PER_TARGET] [TARGET ...]     default: 600 s, every target
# Findings (crash-*, leak-*, timeout-*, oom-*) land in $DSS_FUZZ_WS/findings/<target>/;
# once fixed, commit each to fuzz/regressions/<target>/ (test_fuzz_regressions
# replays them in every test run).
set -euo pipefail

REPO_DIR="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
FUZZ_WS="${DSS_FUZZ_WS:-$REPO_DIR/.ws-fuzz}"
SECONDS_PER_TARGET="${1:-600}"
shift || true
# Every target: fuzz/fuzz_<target>.cpp (fuzz/CMakeLists.txt lists the same).
ALL_TARGETS=()
for source in "$REPO_DIR"/fuzz/fuzz_*.cpp; do
  name="$(basename "$source" .cpp)"
  ALL_TARGETS+=("${name#fuzz_}")
done
TARGETS=("$@")
if ((${#TARGETS[@]} == 0)); then TARGETS=("${ALL_TARGETS[@]}"); fi
JOBS="${DSS_FUZZ_JOBS:-$(nproc)}"

DSS_SETUP_PACKAGES_ONLY=1 "$REPO_DIR/scripts/setup.sh"
mkdir -p "$FUZZ_WS/src"
[[ -e "$FUZZ_WS/src/digital_sun_sensor" ]] || ln -s "$REPO_DIR" "$FUZZ_WS/src/digital_sun_sensor"
export PATH="/usr/bin:$PATH"
echo "[fuzz] building ${TARGETS[*]} in $FUZZ_WS (log: $FUZZ_WS/build.log)" >&2
(cd "$FUZZ_WS" && CC=clang CXX=clang++ /usr/bin/python3 /usr/bin/catkin_make \
  -DPYTHON_EXECUTABLE=/usr/bin/python3 -DCMAKE_BUILD_TYPE=RelWithDebInfo -DDSS_FUZZ=ON \
  -DCATKIN_ENABLE_TESTING=OFF -j"$(nproc)" "${TARGETS[@]/#/fuzz_}" >"$FUZZ_WS/build.log" 2>&1) ||
  { tail -n 30 "$FUZZ_WS/build.log"; echo "[fuzz] build failed" >&2; exit 1; }

run_target() {
  local target="$1" bin="$FUZZ_WS/devel/lib/digital_sun_sensor/fuzz_$1"
  local corpus="$FUZZ_WS/corpus/$target" findings="$FUZZ_WS/findings/$target/" log="$FUZZ_WS/logs/$target.log"
  mkdir -p "$corpus" "$findings" "$(dirname "$log")"
  cp -n "$REPO_DIR/fuzz/seeds/$target/"* "$corpus/" 2>/dev/null || true
  # One thread each (two targets share two cores); leaks are findings too.
  OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 \
    ASAN_OPTIONS="detect_leaks=1:allocator_may_return_null=0" LSAN_OPTIONS="suppressions=$REPO_DIR/fuzz/lsan.supp" \
    UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1" \
    "$bin" "$corpus" -max_total_time="$SECONDS_PER_TARGET" -timeout=30 -rss_limit_mb=6144 -max_len=1048576 \
    -print_final_stats=1 -artifact_prefix="$findings" -close_fd_mask=1 >"$log" 2>&1 || true
  local executions coverage features corpus_size found
  executions="$(grep -oP 'stat::number_of_executed_units: \K[0-9]+' "$log" | tail -n1)"
  coverage="$(grep -oP '\bcov: \K[0-9]+' "$log" | tail -n1)"
  features="$(grep -oP '\bft: \K[0-9]+' "$log" | tail -n1)"
  corpus_size="$(find "$corpus" -type f | wc -l)"
  found="$(find "$findings" -type f \( -name 'crash-*' -o -name 'leak-*' -o -name 'timeout-*' -o -name 'oom-*' \) | wc -l)"
  printf '{"target": "%s", "seconds": %s, "executions": %s, "coverage": %s, "features": %s, "corpus": %s, "findings": %s}\n' \
    "$target" "$SECONDS_PER_TARGET" "${executions:-0}" "${coverage:-0}" "${features:-0}" "$corpus_size" "$found"
}
export -f run_target
export FUZZ_WS REPO_DIR SECONDS_PER_TARGET

results="$(printf '%s\n' "${TARGETS[@]}" | xargs -P "$JOBS" -I{} bash -c 'run_target {}')"
echo "$results"
total_findings="$(echo "$results" | grep -oP '"findings": \K[0-9]+' | awk '{s += $1} END {print s + 0}')"
echo "[fuzz] ${#TARGETS[@]} targets, ${SECONDS_PER_TARGET} s each: $total_findings findings (in $FUZZ_WS/findings)" >&2
[[ "$total_findings" == 0 ]]
