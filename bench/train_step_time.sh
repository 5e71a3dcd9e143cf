#!/usr/bin/env bash
# Step time of lidar-train, for comparing builds or reading modes (lazy reading should stay within
# 5 % of loading everything). Each variant trains --epochs 1 for SHORT and for LONG steps; the
# difference divided by LONG - SHORT is the time per step without start-up, validation and
# checkpoint; the same for CPU time (user + system, all threads), which depends less on the
# machine's load. Variants run interleaved, RUNS times each; medians are printed with the load
# average, and the peak RSS of the long runs.
#
#   bench/train_step_time.sh DATA.h5 RUNS "name=BINARY [lidar-train options]" ...
#   bench/train_step_time.sh sk.h5 5 "main=/tmp/old/lidar-train" "lazy=build/train/lidar-train" \
#       "nocache=build/train/lidar-train --cache-mb 0"
# Environment: SHORT (10), LONG (60), TRAIN_ARGS (the README recipe below), THREADS (2).
set -euo pipefail
if (($# < 3)); then
  sed -n 2,12p "$0" >&2
  exit 2
fi
data=$1 runs=$2
shift 2
short=${SHORT:-10} long=${LONG:-60}
read -r -a recipe <<< "${TRAIN_ARGS:---channels range,class,material --base 8 --depth 3 --batch 2 --crop 256}"
export OMP_WAIT_POLICY=passive
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

seconds() {  # wall s, peak kB, CPU s of one run: seconds <steps> <binary and options...>
  local steps=$1
  shift
  /usr/bin/time -f "%e %M %U %S" -o "$work/time" "$@" --data "$data" "${recipe[@]}" --threads "${THREADS:-2}" \
    --epochs 1 --steps-per-epoch "$steps" --out "$work/ck.h5" --quiet > /dev/null 2> "$work/err" ||
    { cat "$work/err" >&2; exit 1; }
  rm -f "$work/ck.h5"
  awk '{print $1, $2, $3 + $4}' "$work/time"
}

median() { sort -g | awk '{v[NR] = $1} END {print (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2}'; }

echo "load average at start: $(cut -d' ' -f1-3 /proc/loadavg)"
for ((r = 1; r <= runs; ++r)); do
  for variant in "$@"; do
    name=${variant%%=*}
    read -r -a cmd <<< "${variant#*=}"
    read -r ts _ cs < <(seconds "$short" "${cmd[@]}")
    read -r tl kb cl < <(seconds "$long" "${cmd[@]}")
    ms=$(awk -v a="$ts" -v b="$tl" -v s="$short" -v l="$long" 'BEGIN {printf "%.1f", 1000 * (b - a) / (l - s)}')
    cpu=$(awk -v a="$cs" -v b="$cl" -v s="$short" -v l="$long" 'BEGIN {printf "%.1f", 1000 * (b - a) / (l - s)}')
    echo "$ms" >> "$work/$name.ms"
    echo "$cpu" >> "$work/$name.cpu"
    echo "$kb" >> "$work/$name.kb"
    echo "run $r $name: ${ms} ms/step, CPU ${cpu} ms/step (short ${ts} s, long ${tl} s, peak ${kb} kB)"
  done
done
echo "load average at end: $(cut -d' ' -f1-3 /proc/loadavg)"
for variant in "$@"; do
  name=${variant%%=*}
  echo "median $name: $(median < "$work/$name.ms") ms/step (all: $(tr '\n' ' ' < "$work/$name.ms")), CPU" \
       "$(median < "$work/$name.cpu") ms/step (all: $(tr '\n' ' ' < "$work/$name.cpu")), peak RSS" \
       "$(median < "$work/$name.kb") kB, $runs runs"
done
