#!/usr/bin/env bash
# Set up (install, configure, build) and run the whole test suite. With LIDARSIM_ASAN=1 (CI:
# opt-in for CI too until it runs green), the whole suite again, built with AddressSanitizer + UndefinedBehaviorSanitizer
# (and LeakSanitizer) in build-asan/ (issue 13; README, Reliability, has the measured cost).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/bootstrap.sh
build_dir=${LIDARSIM_BUILD_DIR:-build}
ctest --test-dir "$build_dir" --output-on-failure -j"$(nproc)" --timeout 300

if [ "${LIDARSIM_ASAN:-0}" = 1 ]; then
  start=$(date +%s)
  # -O1 -g1 (CMakeLists.txt), no benchmarks: only what ctest runs.
  LIDARSIM_BUILD_DIR=build-asan LIDARSIM_CMAKE_ARGS="-DLIDARSIM_SANITIZE=address,undefined -DLIDARSIM_BENCH=OFF" \
    scripts/bootstrap.sh
  # Leaks are errors too; a sanitizer finding aborts the test (-fno-sanitize-recover).
  ASAN_OPTIONS=detect_leaks=1:abort_on_error=1:strict_string_checks=1 \
  UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  LSAN_OPTIONS=suppressions=$PWD/scripts/lsan.supp \
    ctest --test-dir build-asan --output-on-failure -j"$(nproc)" --timeout 900
  echo "sanitizer pass (build + suite): $(( $(date +%s) - start )) s"
fi
