#!/usr/bin/env bash
# The main job: set up (install what is missing, configure, build), then simulate the bundled
# urban scenario with the bundled models through the whole pipeline and show where the outputs are.
#   scripts/demo.sh [OUT_DIR]        (default out/demo; LIDARSIM_BUILD_DIR picks the build folder,
#                                     default build-demo)
set -euo pipefail
cd "$(dirname "$0")/.."
start=$(date +%s)
scripts/bootstrap.sh --install
installed=$(date +%s)
# Only the command the demo runs and the libraries under it, in a folder of its own (build-demo/,
# so that it never changes the settings of build/): one unity build (a folder's files compiled as
# a few translation units), without the tests, benchmarks and the FMU, whose targets it would
# otherwise configure (the FMU keeps the libraries per file). scripts/test.sh builds the tests and
# scripts/bench.sh the benchmarks, in build/. Same code, same flags: the outputs are the same
# bytes as from a per-file build (docs/testing.md, "The demo's build").
build_dir=${LIDARSIM_BUILD_DIR:-build-demo}
echo "demo: building lidar-infer in $build_dir/ (the first time takes a few minutes on 2 cores)" >&2
# Ninja's progress line: files done of all, and seconds since the build started.
export NINJA_STATUS=${NINJA_STATUS:-"[%f/%t %es] "}
LIDARSIM_BUILD_DIR=$build_dir LIDARSIM_CMAKE_ARGS="-DCMAKE_UNITY_BUILD=ON -DCMAKE_UNITY_BUILD_BATCH_SIZE=16 \
-DLIDARSIM_TESTS=OFF -DLIDARSIM_BENCH=OFF -DLIDARSIM_FMU=OFF ${LIDARSIM_CMAKE_ARGS:-}" \
  scripts/bootstrap.sh --build lidar-infer
built=$(date +%s)
echo "demo: packages $((installed - start)) s, build $((built - installed)) s" >&2
out=${1:-out/demo}
mkdir -p "$out"
# OpenMP threads that spin at barriers lose their core to other processes on a busy machine and
# slow the UNet (at load ~6 on 2 cores, 20 frames: 239 ms/frame sleeping, 375 default, 427 spinning); sleeping costs
# little at 10 Hz. A value set by the caller wins.
export OMP_WAIT_POLICY=${OMP_WAIT_POLICY:-passive}
# No options: data/scenarios/demo_urban.json, data/models/intensity_unet.h5 and
# data/models/kpi_pointrcnn.json, 2 threads.
"$build_dir/infer/lidar-infer" sim --out "$out"
echo
echo "demo: outputs in $out/"
echo "  $out/summary.md      time per stage, real-time factor, objects and points per frame (read this first)"
echo "  $out/bev_NNNN.png    bird's-eye view per frame: ground truth, reported objects, lanes"
echo "  $out/pgm_NNNN.png    PGM channels per frame: range, class, material, predicted intensity"
echo "  $out/cloud_NNNN.pcd  point clouds with intensity (open in CloudCompare or Open3D)"
echo "  $out/objects_NNNN.csv|json, lanes_NNNN.json   object lists and lane polynomials"
echo "demo: it ran $build_dir/infer/lidar-infer; scripts/bootstrap.sh --build builds every command into build/"
