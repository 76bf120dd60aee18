#!/usr/bin/env bash
# Installs every Debian package digital_sun_sensor needs and builds the catkin
# workspace at $DSS_WS (default: <repo>/.ws). Idempotent: a second run only
# rebuilds what changed.
set -euo pipefail

REPO_DIR="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
DSS_WS="${DSS_WS:-$REPO_DIR/.ws}"
BUILD_TYPE="${DSS_BUILD_TYPE:-Release}"

# Debian 12 packages. ROS 1 comes from Debian itself (installed under /usr).
PACKAGES=(
  # toolchain
  build-essential cmake pkg-config git
  # ROS 1 core, build, tools
  ros-core-dev catkin rosbash rosout python3-roslaunch python3-rostopic python3-yaml
  python3-rosbag python3-rostest librostest-dev python3-rosunit python3-catkin-pkg
  python3-sensor-msgs python3-geometry-msgs  # rostopic on images and attitudes (scripts/soak.sh)
  libtf2-ros-dev tf2-tools libtf2-geometry-msgs-dev libcv-bridge-dev librosbag-dev
  libdiagnostic-updater-dev libdiagnostic-msgs-dev libnodelet-dev libnodeletlib-dev
  libnodeletlib-tools pluginlib-dev libsensor-msgs-dev libgeometry-msgs-dev
  libstd-msgs-dev libstd-srvs-dev ros-message-generation ros-message-runtime
  # numerics
  libtorch-dev libopenblas0-pthread libopenblas-pthread-dev libeigen3-dev libfftw3-dev
  # images, config, tests
  libopencv-dev libyaml-cpp-dev googletest libgtest-dev
  # fuzzing (scripts/fuzz.sh): clang with libFuzzer and the sanitizers
  clang libclang-rt-14-dev
)

missing=()
for pkg in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$pkg")
  fi
done
if ((${#missing[@]})); then
  echo "[setup] installing ${#missing[@]} Debian packages: ${missing[*]}"
  SUDO=""
  if [[ $EUID -ne 0 ]]; then SUDO="sudo"; fi
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

# libtorch must use the pthread OpenBLAS (the reference BLAS is ~6x slower).
if command -v update-alternatives >/dev/null; then
  blas_alt="$(update-alternatives --list libblas.so.3-x86_64-linux-gnu 2>/dev/null | grep openblas-pthread | head -n1 || true)"
  if [[ -n "$blas_alt" ]]; then
    current="$(readlink -f /etc/alternatives/libblas.so.3-x86_64-linux-gnu || true)"
    if [[ "$current" != "$(readlink -f "$blas_alt")" ]]; then
      ${SUDO:-} update-alternatives --set libblas.so.3-x86_64-linux-gnu "$blas_alt"
    fi
  fi
fi

# DSS_SETUP_PACKAGES_ONLY=1: stop here (scripts/fuzz.sh builds its own workspace).
if [[ "${DSS_SETUP_PACKAGES_ONLY:-0}" == 1 ]]; then exit 0; fi

# Catkin workspace with the repository linked in as its only package.
mkdir -p "$DSS_WS/src"
if [[ ! -e "$DSS_WS/src/digital_sun_sensor" ]]; then
  ln -s "$REPO_DIR" "$DSS_WS/src/digital_sun_sensor"
fi

export PATH="/usr/bin:$PATH"
cd "$DSS_WS"
echo "[setup] building workspace $DSS_WS ($BUILD_TYPE)"
/usr/bin/python3 /usr/bin/catkin_make \
  -DPYTHON_EXECUTABLE=/usr/bin/python3 \
  -DCMAKE_BUILD_TYPE="$BUILD_TYPE" \
  -j"$(nproc)" ${DSS_CATKIN_ARGS:-}
echo "[setup] done: source $DSS_WS/devel/setup.bash"
