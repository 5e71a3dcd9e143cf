#!/usr/bin/env bash
# Intensity held out by place (docs/intensity.md, "Held out by place"): each place of the shared
# data held out whole in turn, the UNet trained with lidar-train on the other places on the same
# grid and intensity scale (bench_intensity_places --plan decides, data/place_split.h), then
# scored on every cell of the held-out place beside the lookups fitted on the same training places,
# with the histogram intersection against its real-vs-real ceiling; checkpoints with a spread head
# are also scored sampled (draw seeds 1, 2, 3).
#   scripts/intensity_places.sh [OUT_DIR]      default out/intensity_places
# Writes OUT_DIR/places.json and OUT_DIR/places.md (atomically, by bench_intensity_places); the
# imports and checkpoints stay in OUT_DIR (a rerun reuses them; delete them to redo).
# EPOCHS (default 10: a third of the recipe's 30, for a shared 2-core machine), STEPS (100),
# SEED (1), THREADS (1), DATA (default ../shared/data) change the run.
set -euo pipefail
cd "$(dirname "$0")/.."
build=${LIDARSIM_BUILD_DIR:-build}
data=${DATA:-${LIDARSIM_SHARED_DATA:-$(cd .. && pwd)/shared/data}}
out=${1:-out/intensity_places}
epochs=${EPOCHS:-10} steps=${STEPS:-100} seed=${SEED:-1} threads=${THREADS:-1}
export OMP_WAIT_POLICY=passive
mkdir -p "$out"
say() { echo "intensity_places: $*" >&2; }

# One import per place. The KITTI object frames of both folders are one place group (frames of
# different drives, none of them sequence 00 or 08): one folder of symlinks.
import() {  # name flag dir
  [[ -f $out/$1.h5 ]] && { say "$1: $out/$1.h5 exists"; return; }
  say "import $1 ($2 $3)"
  nice "$build/data/lidar-data" import "$2" "$3" --out "$out/$1.h5" --quiet
}
kitti="$out/kitti_object_all/training"
mkdir -p "$kitti"/{velodyne,label_2,calib}
for src in "$data"/kitti-object-sample "$data"/kitti-object-more; do
  for sub in velodyne label_2 calib; do
    for f in "$src"/training/$sub/*; do ln -sf "$f" "$kitti/$sub/"; done
  done
done
import seq00 --semantickitti "$data/semantickitti-seq00-sample"
import seq08 --semantickitti-mos "$data/semantickitti-seq08-mos-sample"
import kitti_object --kitti-object "$kitti"
import nuscenes --nuscenes-lidarseg "$data/nuscenes-lidarseg-scene"
import rellis3d --rellis3d "$data/rellis3d-os1-sample"

sets="seq00=$out/seq00.h5,seq08=$out/seq08.h5,kitti_object=$out/kitti_object.h5,nuscenes=$out/nuscenes.h5,rellis3d=$out/rellis3d.h5"
bench="$build/bench/bench_intensity_places"
# Variants, name:channels:extra lidar-train flags: the recipe's channels, range alone (seq08 has no
# classes: class 0 everywhere), and range alone with the epoch chosen on an inner region of the
# training places' columns (--early-stop with --val), without and with the spread head (whose scale
# factor and residual table are fitted on that inner region: nothing of the held-out place), and
# with the zero head too (P(intensity = 0), trained on the training cells).
# VARIANTS="range_spread range_zero" runs only those.
all_variants=("rcm:range,class,material:" "range:range:" "range_es:range:--early-stop"
              "range_spread:range:--heads=mean,log_scale_laplace --early-stop"
              "range_zero:range:--heads=mean,log_scale_laplace,zero_logit --early-stop")
variants=()
for v in "${all_variants[@]}"; do
  [[ -z ${VARIANTS:-} || " $VARIANTS " == *" ${v%%:*} "* ]] && variants+=("$v")
done
"$bench" --data "$sets" --plan > "$out/plan.txt"
while IFS='|' read -r _ held train excluded; do
  [[ -n $excluded ]] && say "$held held out: not trained on $excluded"
  if [[ -z $train ]]; then say "$held held out: no place on its grid and scale trains for it"; continue; fi
  files=$(echo "$train" | tr ',' '\n' | sed "s|.*|$out/&.h5|" | paste -sd,)
  for v in "${variants[@]}"; do
    name=${v%%:*} rest=${v#*:}; channels=${rest%%:*}; read -r -a flags <<< "${rest#*:}"; ck="$out/$held.$name.h5"
    if [[ -f $ck && ! -f $ck.running ]]; then say "$held held out, $name: $ck exists"; continue; fi
    say "$held held out, $name: training on $train ($epochs x $steps steps), scored on $held"
    rm -f "$ck"; touch "$ck.running"
    nice "$build/train/lidar-train" --data "$files" --val "$out/$held.h5" --channels "$channels" \
      --base 8 --depth 3 --batch 2 --crop 256 --epochs "$epochs" --steps-per-epoch "$steps" \
      --seed "$seed" --threads "$threads" ${flags[@]+"${flags[@]}"} --out "$ck" --log "$out/$held.$name.csv" \
      > "$out/$held.$name.out" 2> "$out/$held.$name.log"
    rm -f "$ck.running"
    say "$held held out, $name: $(tail -1 "$out/$held.$name.csv")"
  done
done < "$out/plan.txt"
names=$(for v in "${variants[@]}"; do echo "${v%%:*}"; done | paste -sd,)
nice "$bench" --data "$sets" --models "$out" --variants "$names" --seeds 1,2,3 --out "$out/places"
say "wrote $out/places.json and $out/places.md"
