#!/usr/bin/env bash
# Set up (install, configure, build) and run the test suite; then, with LIDARSIM_ASAN=1, the unit
# tests again, built with AddressSanitizer + UndefinedBehaviorSanitizer (and LeakSanitizer) in
# build-asan/. CI runs the normal pass only: the sanitized pass would double the run (measured in
# docs/testing.md) and take it past the budget below; run it before merging changes to readers,
# kernels, checkpoints or the FMU.
#
# Which tests run where (labels, tests/CMakeLists.txt; docs/testing.md):
#   normal pass     labels unit and statistical (every test but the long campaigns)
#   sanitized pass  label unit (readers, writers, kernels and their gradient checks, checkpoints,
#                   datasets, OSI and the FMU, the commands' bad input, the loops' smoke runs),
#                   with LIDARSIM_ISA=avx2: the baseline kernels (nn/cpu_features.h), so the AVX2
#                   path is tested on every machine and the normal pass tests the CPU's widest
#   at avx2         labels unit:nn and unit:train again with LIDARSIM_ISA=avx2, on CPUs with AVX-512
#                   (the normal pass ran their widest kernels); labels are <kind>:<folder>
#   never here      label long: scripts/bench.sh --long, or ctest -L long
# Budget: CI gives 90 minutes; the whole run must take at most half of that on a 2-core machine
# three times slower than the fastest we have (measured: docs/testing.md). The time of each phase
# is printed at the end.
set -euo pipefail
cd "$(dirname "$0")/.."
asan=${LIDARSIM_ASAN:-0}

phases=()
phase() {  # phase NAME COMMAND...: run it, note its wall time, keep its exit status
  local name=$1 start rc=0
  shift
  start=$(date +%s)
  "$@" || rc=$?
  phases+=("$(printf '%-26s %5d s%s' "$name" $(($(date +%s) - start)) "$( ((rc)) && echo "  (failed: exit $rc)")")")
  return $rc
}
report() {
  echo
  echo "test.sh: time per phase"
  for p in "${phases[@]}"; do echo "  $p"; done
  echo "  $(printf '%-26s %5d s' total $(($(date +%s) - run_start)))"
}
run_start=$(date +%s)
trap report EXIT

build_dir=${LIDARSIM_BUILD_DIR:-build}
phase "install packages" scripts/bootstrap.sh --install
# A unity build (a folder's files compiled as a few translation units: the headers are parsed and
# their templates compiled once per unit, not per file) without the benchmarks, which no test runs:
# half the build's time (docs/testing.md). Day-to-day builds (scripts/bootstrap.sh) stay per file.
test_build() {
  LIDARSIM_CMAKE_ARGS="-DCMAKE_UNITY_BUILD=ON -DCMAKE_UNITY_BUILD_BATCH_SIZE=16 -DLIDARSIM_BENCH=OFF ${LIDARSIM_CMAKE_ARGS:-}" scripts/bootstrap.sh --build
}
phase "build" test_build
# A failing normal pass does not skip the sanitized one: the run reports both ctest summaries.
status=0
phase "tests" ctest --test-dir "$build_dir" --output-on-failure -j"$(nproc)" --timeout 120 -LE long || status=1
# The normal pass ran the CPU's widest kernels; where the CPU has more than the baseline, the
# engine's unit tests (kernels, gradient checks, training bits) run again on the AVX2 kernels, so
# every machine tests the path every x86-64-v3 CPU runs (labels unit:nn and unit:train).
if grep -qw avx512f /proc/cpuinfo 2>/dev/null; then
  LIDARSIM_ISA=avx2 phase "tests at avx2 (nn, train)" ctest --test-dir "$build_dir" --output-on-failure -j"$(nproc)" \
    --timeout 120 -L '^unit:(nn|train)$' || status=1
fi

if [ "$asan" = 1 ]; then
  # -O1 -g1 (CMakeLists.txt), no benchmarks: only what ctest runs.
  asan_build() {
    LIDARSIM_BUILD_DIR=build-asan LIDARSIM_CMAKE_ARGS="-DLIDARSIM_SANITIZE=address,undefined -DCMAKE_UNITY_BUILD=ON -DCMAKE_UNITY_BUILD_BATCH_SIZE=16 -DLIDARSIM_BENCH=OFF" \
      scripts/bootstrap.sh --build
  }
  phase "sanitized build" asan_build
  # ctest starts the tests that took longest last time first, so on a fresh build-asan/ it takes
  # the normal pass's times (the same ranking, 3-10x shorter) and no long test starts last.
  costs=Testing/Temporary/CTestCostData.txt
  if [ ! -f "build-asan/$costs" ] && [ -f "$build_dir/$costs" ]; then
    mkdir -p "build-asan/Testing/Temporary" && cp "$build_dir/$costs" "build-asan/$costs"
  fi
  # Leaks are errors too; a sanitizer finding aborts the test (-fno-sanitize-recover).
  LIDARSIM_ISA=avx2 \
  ASAN_OPTIONS=detect_leaks=1:abort_on_error=1:strict_string_checks=1 \
  UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  LSAN_OPTIONS=suppressions=$PWD/scripts/lsan.supp \
    phase "sanitized tests" ctest --test-dir build-asan --output-on-failure -j"$(nproc)" --timeout 300 -L unit \
    || status=1
fi
exit $status
