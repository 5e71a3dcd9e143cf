#!/usr/bin/env bash
# Engine vs PyTorch on unet-ref, in one run: installs the peer's Debian packages when missing
# (python3-torch, python3-h5py, and libopenblas0-openmp, which becomes the system libblas.so.3
# that Debian's torch links, instead of the slow reference BLAS), builds bench_unet_vs_torch and
# runs it. Extra arguments go to the benchmark (e.g. --reps 9 --threads 2 --json bench.json).
# Run on an otherwise idle machine: the numbers are medians, but a busy CPU still skews them.
set -euo pipefail
cd "$(dirname "$0")/.."

packages=(python3-torch python3-h5py libopenblas0-openmp)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "bench: installing ${missing[*]}" >&2
  sudo_cmd=(); [ "$(id -u)" -eq 0 ] || sudo_cmd=(sudo)
  "${sudo_cmd[@]}" apt-get update -qq
  DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi
# Say which BLAS torch will get (the alternative libopenblas0-openmp registers at priority 95).
if command -v update-alternatives >/dev/null; then
  blas=$(update-alternatives --query libblas.so.3-x86_64-linux-gnu 2>/dev/null | sed -n 's/^Value: //p')
  echo "bench: libblas.so.3 -> ${blas:-unknown}" >&2
fi

build_dir=${LIDARSIM_BUILD_DIR:-build}
cmake -S . -B "$build_dir" -DCMAKE_BUILD_TYPE=${CMAKE_BUILD_TYPE:-Release} >/dev/null
cmake --build "$build_dir" --target bench_unet_vs_torch -j"$(nproc)"
"$build_dir/bench/bench_unet_vs_torch" --python /usr/bin/python3 "$@"
