#!/usr/bin/env bash
# Fuzz every reader with libFuzzer (clang, ASan + UBSan): scripts/fuzz.sh [seconds per target] [target[:seconds]...]
# LIDARSIM_FUZZ_RUNS=N stops a target after N executions (fast targets need not use all their time).
# LIDARSIM_FUZZ_JOBS=N runs N targets at a time (default 1), in the order given.
# LIDARSIM_FUZZ_UNTIL="19:25" (anything `date -d` reads): no target runs past that time.
# Builds build-fuzz/ with clang (installed here if missing; the normal build never needs it),
# seeds each target from data/, ../shared/data and fuzz/regressions/, runs the targets one after
# the other at nice 19 and prints executions, crashes, hangs (timeouts), leaks and out-of-memory
# per target. Findings land in fuzz/regressions/<target>/, which tests/fuzz replays in every build.
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-60}
shift || true
root=$PWD
shared=${LIDARSIM_SHARED_DATA:-$root/../shared/data}
build=${LIDARSIM_FUZZ_BUILD_DIR:-build-fuzz}

packages=(clang libclang-rt-dev libomp-dev)
scripts/install_packages.sh fuzz "${packages[@]}"

targets=$(echo $(cat fuzz/targets.txt))
(($#)) && targets="$*"
declare -A time_of  # target:seconds given on the command line
for t in $targets; do [[ $t == *:* ]] && time_of[${t%%:*}]=${t#*:}; done
targets=$(for t in $targets; do echo "${t%%:*}"; done | xargs)
launcher=()
command -v ccache >/dev/null && launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache -DCMAKE_C_COMPILER_LAUNCHER=ccache)
CC=clang CXX=clang++ cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DLIDARSIM_FUZZ=ON \
  -DLIDARSIM_SANITIZE=address,undefined "${launcher[@]}" >/dev/null
nice -n 19 cmake --build "$build" -j2 --target $(for t in $targets; do echo "fuzz_$t"; done) >/dev/null

# Seeds: small pieces of real files (a libFuzzer input is at most -max_len bytes; scans are MBs).
seeds=$build/seeds
for t in $targets; do rm -rf "${seeds:?}/$t"; done  # another run's seeds stay in use
seed() {  # seed TARGET FILE [BYTES]
  [[ " $targets " == *" $1 "* ]] || return 0
  mkdir -p "$seeds/$1"
  [ -f "$2" ] || return 0
  head -c "${3:-65536}" "$2" > "$seeds/$1/$(echo "$2" | md5sum | cut -c1-12)"
}
for f in $(ls data/samples/semantickitti/sequences/*/velodyne/*.bin "$shared"/kitti-object-*/training/velodyne/*.bin 2>/dev/null | head -4); do
  seed velodyne "$f" 4096
done
for f in $(ls "$shared"/kitti-object-*/training/label_2/*.txt 2>/dev/null | head -8); do seed kitti_object_label "$f"; done
for f in $(ls "$shared"/kitti-object-*/training/calib/*.txt "$shared"/kitti-tracking-gt-pointrcnn/calib/*.txt 2>/dev/null | head -8); do
  seed kitti_calib "$f"
done
for f in $(ls "$shared"/kitti-tracking-gt-pointrcnn/label_02/*.txt 2>/dev/null | head -4); do seed tracking_labels "$f" 8192; done
for f in $(ls "$shared"/kitti-tracking-gt-pointrcnn/detection/*/*.txt 2>/dev/null | head -6); do seed tracking_detections "$f" 8192; done
for f in "$shared"/kitti-tracking-gt-pointrcnn/*.seqmap*; do seed tracking_seqmap "$f"; done
for f in data/scenarios/*.json; do seed scenario "$f" 1000000; done
for f in data/models/*.json; do seed kpi_model "$f" 1000000; done
# HDF5 seeds must fit in -max_len whole (a cut file only reaches the "truncated" check): the
# bundled scan imported at a small grid (20 KB), and a UNet of base 2, depth 1 trained one step
# on it, with its optimizer (27 KB). The bundled models (0.2-0.5 MB) would be cut.
if [ -x build/data/lidar-data ]; then
  build/data/lidar-data import --quiet --semantickitti data/samples/semantickitti --columns 16 \
    --channels incidence --out "$build/seed_dataset.h5" >/dev/null 2>&1 && seed dataset "$build/seed_dataset.h5" 10000000
fi
if [ -x build/train/lidar-train ] && [ -f "$build/seed_dataset.h5" ]; then
  OMP_WAIT_POLICY=passive build/train/lidar-train --data "$build/seed_dataset.h5" --split interleaved --channels range \
    --epochs 1 --steps-per-epoch 1 --base 2 --depth 1 --threads 1 --quiet --out "$build/seed_checkpoint.h5" >/dev/null 2>&1 &&
    seed checkpoint "$build/seed_checkpoint.h5" 10000000
fi
for f in "$shared"/ouster-sample-pcaps/*.json; do seed ouster_metadata "$f"; done
# The captures as a 32-beam, 512-column sensor sends them (the target's metadata): 10-27 packets
# across a frame's end.
if [[ " $targets " == *" ouster_pcap "* ]]; then
  mkdir -p "$seeds/ouster_pcap"
  for f in "$shared"/ouster-sample-pcaps/*.pcap; do python3 fuzz/ouster_seed.py "$f" "$seeds/ouster_pcap/$(basename "$f")"; done
fi
for f in "$shared"/nuscenes-sample-frame/*.pcd.bin; do seed nuscenes "$f" 4000; done
# RELLIS-3D: 32 columns of 64 points of the .bin, then their labels (the target splits at 16/20).
for f in "$shared"/rellis3d-os1-sample/*.bin; do
  mkdir -p "$seeds/rellis3d"
  { head -c 32768 "$f"; head -c 8192 "${f%.bin}.label"; } > "$seeds/rellis3d/$(basename "$f")"
done
# PLY: the sample's header with its vertex count cut to what fits in 64 KB, and a small ASCII cloud.
for f in "$shared"/rellis3d-os1-sample/*.ply; do
  mkdir -p "$seeds/ply"
  python3 - "$f" "$seeds/ply/$(basename "$f")" <<'PY'
import re, sys
data = open(sys.argv[1], 'rb').read()
end = data.index(b'end_header\n') + len(b'end_header\n')
header = data[:end].decode()
n = int(re.search(r'element vertex (\d+)', header).group(1))
stride = (len(data) - end) // n
keep = (65536 - end - 16) // stride
open(sys.argv[2], 'wb').write(re.sub(r'element vertex \d+', 'element vertex %d' % keep, header).encode() + data[end:end + keep * stride])
PY
done
mkdir -p "$seeds/ply"
printf 'ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nproperty ushort reflectivity\nend_header\n1 2 3 40\n-1.5 0 2e1 65535\n' > "$seeds/ply/ascii"
for f in data/ontologies/*.csv; do seed class_table "$f"; done
for f in data/sensors/*.json; do seed sensor_layout "$f"; done
# OSI: the first frames of each bundled scenario as a SensorView trace (lidar-infer osi-trace).
# A demo_urban SensorView is 95 KB (its lanes as 3,000 boundary points), more than -max_len, so
# the seeds are the scenarios with every lane cut to its first 6 m: 3 frames in about 20 KB.
if [ -x build/infer/lidar-infer ]; then
  mkdir -p "$seeds/osi_trace"
  for f in data/scenarios/*.json; do
    python3 - "$f" "$build/short_lanes.json" <<'PY'
import json, sys
d = json.load(open(sys.argv[1]))
for lane in d.get('lanes', []):
    (x0, y0), (x1, y1) = lane['points'][0], lane['points'][1]
    n = max(((x1 - x0) ** 2 + (y1 - y0) ** 2) ** 0.5, 1e-9)
    lane['points'] = [[x0, y0], [x0 + (x1 - x0) * 6 / n, y0 + (y1 - y0) * 6 / n]]
json.dump(d, open(sys.argv[2], 'w'))
PY
    build/infer/lidar-infer osi-trace --scenario "$build/short_lanes.json" --frames 3 \
      --out "$seeds/osi_trace/$(basename "$f" .json).osi" >/dev/null 2>&1 || true
  done
fi

# One target: libFuzzer until -runs or the time is up, its log in $build/logs/<target>.log.
fuzz_one() {
  local t=$1 corpus=$build/corpus/$1 regressions=fuzz/regressions/$1 log=$build/logs/$1.log
  mkdir -p "$corpus" "$regressions" "$seeds/$t" "$(dirname "$log")"
  local time=${time_of[$t]:-$seconds}
  if [ -n "${LIDARSIM_FUZZ_UNTIL:-}" ]; then
    local left=$(($(date -d "$LIDARSIM_FUZZ_UNTIL" +%s) - $(date +%s)))
    ((left < time)) && time=$((left > 1 ? left : 1))
  fi
  # Leaks are checked by LeakSanitizer after an input whose mallocs and frees do not match
  # (detect_leaks=1), and at exit. A hang is an input over 60 s: at nice 19 on a loaded machine
  # a 0.25 s input once took 13 s of wall time.
  # The CPU time it got goes to the log too: on a shared machine exec/s says more about the load.
  local TIMEFORMAT='cpu_seconds: %U %S'
  { time ASAN_OPTIONS=detect_leaks=1:allocator_may_return_null=1 UBSAN_OPTIONS=halt_on_error=1:print_stacktrace=1 \
  LSAN_OPTIONS=suppressions=$root/scripts/lsan.supp \
    nice -n 19 "$build/fuzz/fuzz_$t" -max_total_time="$time" -runs="${LIDARSIM_FUZZ_RUNS:--1}" -timeout=60 \
      -rss_limit_mb=2048 -max_len=65536 \
      -print_final_stats=1 -artifact_prefix="$regressions/" "$corpus" "$seeds/$t" "$regressions" >"$log" 2>&1 || true; } 2>>"$log"
}
parallel=${LIDARSIM_FUZZ_JOBS:-1}
stamp=$build/logs/started
mkdir -p "$build/logs" && touch "$stamp"
for t in $targets; do
  while (($(jobs -rp | wc -l) >= parallel)); do wait -n || true; done
  fuzz_one "$t" &
done
wait

printf "%-20s %12s %8s %10s %8s %8s %6s %6s\n" target execs exec/s exec/cpu-s crashes hangs leaks ooms
for t in $targets; do
  regressions=fuzz/regressions/$t
  log=$build/logs/$t.log
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
  rate=$(sed -n 's/^stat::average_exec_per_sec: *//p' "$log" | tail -1)
  cpu_rate=$(awk -v n="${execs:-0}" '/^cpu_seconds:/ {c = $2 + $3} END {if (c > 0) printf "%.0f", n / c; else print "?"}' "$log")
  count() { find "$regressions" -name "$1-*" -newer "$stamp" | wc -l; }  # this run's findings
  printf "%-20s %12s %8s %10s %8s %8s %6s %6s\n" "$t" "${execs:-?}" "${rate:-?}" "$cpu_rate" "$(count crash)" "$(count timeout)" "$(count leak)" "$(count oom)"
done
echo "logs: $build/logs/; findings (if any): fuzz/regressions/<target>/ (replayed by tests/fuzz)"
