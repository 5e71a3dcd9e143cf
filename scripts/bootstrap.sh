#!/usr/bin/env bash
# Install what lidarsim needs (Debian packages, only those missing), configure and build.
# Idempotent: a second run installs nothing and rebuilds only what changed.
set -euo pipefail
cd "$(dirname "$0")/.."

# openmpi-bin, libopenmpi-dev: optional, they turn on `mpirun -np N lidar-train` (LIDARSIM_MPI).
packages=(cmake g++ make libeigen3-dev libhdf5-dev libcxxopts-dev libgtest-dev libgmock-dev
          nlohmann-json3-dev libpng-dev libprotobuf-dev protobuf-compiler libpcap-dev
          openmpi-bin libopenmpi-dev)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "bootstrap: installing ${missing[*]}" >&2
  sudo_cmd=(); [ "$(id -u)" -eq 0 ] || sudo_cmd=(sudo)
  "${sudo_cmd[@]}" apt-get update -qq
  DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

build_dir=${LIDARSIM_BUILD_DIR:-build}
# ccache, where installed, makes rebuilds in other checkouts of the same tree nearly free.
# Paths below the source folder enter ccache's keys relative to it (CCACHE_BASEDIR), so a clone
# elsewhere (CI) gets hits too.
launcher=()
if command -v ccache >/dev/null; then
  launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache -DCMAKE_C_COMPILER_LAUNCHER=ccache)
  export CCACHE_BASEDIR=$PWD
fi
# LIDARSIM_CMAKE_ARGS: extra settings, e.g. the sanitizer build of scripts/test.sh.
read -r -a extra <<< "${LIDARSIM_CMAKE_ARGS:-}"
cmake -S . -B "$build_dir" -DCMAKE_BUILD_TYPE=${CMAKE_BUILD_TYPE:-Release} "${launcher[@]}" "${extra[@]}" >/dev/null
cmake --build "$build_dir" -j"$(nproc)"
