#!/usr/bin/env bash
# Crash safety of lidar-train: kill it with SIGKILL at random moments, resume, and compare the
# final checkpoint byte for byte with an uninterrupted run.
#   scripts/crash_test.sh [--count N] [--build DIR]     (CI runs --count 5 through tests/e2e)
set -euo pipefail
cd "$(dirname "$0")/.."
count=20
build=${LIDARSIM_BUILD_DIR:-build}
while (($#)); do
  case $1 in
    --count) count=$2; shift 2 ;;
    --build) build=$2; shift 2 ;;
    *) echo "usage: $0 [--count N] [--build DIR]" >&2; exit 2 ;;
  esac
done
export OMP_WAIT_POLICY=passive
work=$(mktemp -d "${TMPDIR:-/tmp}/lidarsim_crash.XXXXXX")
trap 'rm -rf "$work"' EXIT
"$build/data/lidar-data" import --quiet --semantickitti data/samples/semantickitti --columns 256 \
  --channels incidence --out "$work/set.h5" >/dev/null
# Small UNet, few steps: the whole run takes about a second, so kills land in every phase
# (steps, validation, checkpoint writes).
train=("$build/train/lidar-train" --quiet --data "$work/set.h5" --channels range,class,material,incidence
       --base 4 --depth 2 --epochs 4 --steps-per-epoch 6 --crop 64 --batch 2 --threads 1 --seed 3)

start=$(date +%s%N)
"${train[@]}" --out "$work/reference.h5" >/dev/null
duration_ms=$(( ($(date +%s%N) - start) / 1000000 ))
echo "uninterrupted run: ${duration_ms} ms"

failures=0
for ((i = 1; i <= count; i++)); do
  out=$work/run$i.h5
  kills=""
  # Up to three kills per run, each at a random moment of what remains.
  for k in 1 2 3; do
    "${train[@]}" --resume --out "$out" >/dev/null 2>&1 &
    pid=$!
    delay=$(( RANDOM % (duration_ms + 1) ))
    sleep "$(printf '%d.%03d' $((delay / 1000)) $((delay % 1000)))"
    if kill -9 "$pid" 2>/dev/null; then kills+=" ${delay}ms"; fi
    wait "$pid" 2>/dev/null || true
  done
  "${train[@]}" --resume --out "$out" >/dev/null 2>&1
  if cmp -s "$work/reference.h5" "$out"; then result=identical; else result=DIFFERENT; failures=$((failures + 1)); fi
  left=$(ls "$work" | grep -c '\.tmp\.' || true)
  [ "$left" -eq 0 ] || { result+=", $left temporaries left"; failures=$((failures + 1)); }
  echo "run $i: killed at${kills:- (finished first)}; resumed checkpoint $result"
done
echo "$((count - failures)) of $count runs ended byte-identical with no temporaries left"
[ "$failures" -eq 0 ]
