#!/usr/bin/env bash
# Set up (install, configure, build) and run the whole test suite; then, in CI (CI set) or with
# LIDARSIM_ASAN=1, the whole suite again, built with AddressSanitizer + UndefinedBehaviorSanitizer
# (and LeakSanitizer) in build-asan/ (issue 13; README, Reliability, has the measured cost).
# LIDARSIM_ASAN=0 skips the sanitized pass in CI too.
set -euo pipefail
cd "$(dirname "$0")/.."
case "${CI:-}" in "" | 0 | false) in_ci=0 ;; *) in_ci=1 ;; esac
asan=${LIDARSIM_ASAN:-$in_ci}

scripts/bootstrap.sh
build_dir=${LIDARSIM_BUILD_DIR:-build}
# A failing normal pass does not skip the sanitized one: CI reads both ctest summaries.
status=0
ctest --test-dir "$build_dir" --output-on-failure -j"$(nproc)" --timeout 300 || status=1

if [ "$asan" = 1 ]; then
  start=$(date +%s)
  # -O1 -g1 (CMakeLists.txt), no benchmarks: only what ctest runs.
  LIDARSIM_BUILD_DIR=build-asan LIDARSIM_CMAKE_ARGS="-DLIDARSIM_SANITIZE=address,undefined -DLIDARSIM_BENCH=OFF" \
    scripts/bootstrap.sh
  # ctest starts the tests that took longest last time first, so on a fresh build-asan/ it takes
  # the normal pass's times (the same ranking, 3-10x shorter) and no long test starts last.
  costs=Testing/Temporary/CTestCostData.txt
  if [ ! -f "build-asan/$costs" ] && [ -f "$build_dir/$costs" ]; then
    mkdir -p "build-asan/Testing/Temporary" && cp "$build_dir/$costs" "build-asan/$costs"
  fi
  # Leaks are errors too; a sanitizer finding aborts the test (-fno-sanitize-recover).
  ASAN_OPTIONS=detect_leaks=1:abort_on_error=1:strict_string_checks=1 \
  UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  LSAN_OPTIONS=suppressions=$PWD/scripts/lsan.supp \
    ctest --test-dir build-asan --output-on-failure -j"$(nproc)" --timeout 900 || status=1
  echo "sanitizer pass (build + suite): $(( $(date +%s) - start )) s"
fi
exit $status
