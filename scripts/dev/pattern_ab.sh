#!/bin/bash
# Time two revisions of the pattern estimator (thesis_ca's image-alone
# answer) against each other: scripts/dev/pattern_ab.sh REV_A REV_B
# [CONFIG] [IMAGES] [BLOCKS]. Each revision's pattern sources (baseline/
# pattern_*.cpp, design_canvases.cpp) are built into a plugin against the
# workspace's libdss_core (build it first: scripts/setup.sh); the rest of the
# library is the workspace's. Developer tool: see docs/sscnn.md#measured-speed.
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
a=$1 b=$2 config=${3:-$root/config/sensors/thesis_ca.yaml} images=${4:-40} blocks=${5:-30}
lib=$root/.ws/devel/lib
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
flags=(-O3 -DNDEBUG -std=gnu++17 -isystem /usr/include/eigen3 -isystem /usr/include/opencv4)
links=(-L"$lib" -ldss_core -lopencv_core -lopencv_imgproc -Wl,-rpath,"$lib")
for side in a b; do
  rev=${!side}
  mkdir -p "$work/$side"
  git -C "$root" archive "$rev" include src/baseline | tar -x -C "$work/$side"
  s=$work/$side/src/baseline
  g++ "${flags[@]}" -fPIC -shared -fvisibility=hidden -Wl,-Bsymbolic -I"$work/$side/include" \
    "$root/scripts/dev/pattern_ab_plugin.cpp" "$s"/pattern_estimator.cpp "$s"/pattern_solve.cpp \
    "$s"/pattern_template.cpp "$s"/design_canvases.cpp -o "$work/$side.so" "${links[@]}"
done
g++ "${flags[@]}" -I"$root/include" "$root/scripts/dev/pattern_ab.cpp" -o "$work/pattern_ab" "${links[@]}" -ldl
taskset -c 0 "$work/pattern_ab" "$config" "$images" "$blocks" "$work/a.so" "$work/b.so"
