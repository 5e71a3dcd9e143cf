#!/usr/bin/env bash
# The README's performance table in one command: the engine against PyTorch on unet-ref (both in
# this run: bench_unet_vs_torch starts the PyTorch peer itself), the simulation pipeline and the
# object-level model (bench_pipeline; no peer), optionally the growth bench (--growth: bench_growth,
# which also redraws docs/growth.png). Prints a Markdown table with ours, the peer's and the
# ratio side by side, the machine, the date and the load; --write-readme puts it into README.md
# between the "bench.sh table" markers. --rounds N (default 3) repeats the engine and pipeline
# benches N times and reports the median of the rounds (ratios: the median of each round's ratio,
# with the range), because a shared machine moves single runs by 10-20 %.
#
# Installs the peer's Debian packages when missing (python3-torch, python3-h5py, and
# libopenblas0-openmp, which becomes the system libblas.so.3 that Debian's torch links, instead of
# the slow reference BLAS). Options: --reps N (engine rows, default 7), --runs N (pipeline runs,
# default 5), --rounds N (default 3), --growth, --write-readme, --write-docs (the table also into
# docs/performance.md's tables per CPU family, keyed by vendor, family and model: one table per
# CPU kind, replaced when the same kind is measured again), --out DIR (JSON results, default build/bench-results),
# --no-build (use the benches already built, e.g. while another build runs in the same tree);
# anything after -- goes to bench_unet_vs_torch (e.g. -- --threads 2).
# --long runs the statistical campaigns instead (the tests labelled long, tests/CMakeLists.txt:
# minutes each, never part of scripts/test.sh; docs/testing.md) and nothing else.
# Run on an otherwise idle machine: the numbers are medians, but a busy CPU still skews them.
set -euo pipefail
cd "$(dirname "$0")/.."

reps=7 runs=5 rounds=3 growth=0 write_readme=0 write_docs=0 build=1 out="" long=0
extra=()
while (($#)); do
  case "$1" in
    --reps) reps=$2; shift 2 ;;
    --runs) runs=$2; shift 2 ;;
    --rounds) rounds=$2; shift 2 ;;
    --growth) growth=1; shift ;;
    --write-readme) write_readme=1; shift ;;
    --write-docs) write_docs=1; shift ;;
    --no-build) build=0; shift ;;
    --out) out=$2; shift 2 ;;
    --long) long=1; shift ;;
    --) shift; extra=("$@"); break ;;
    *) echo "bench.sh: unknown option $1 (see the comment at the top)" >&2; exit 2 ;;
  esac
done

if ((long)); then
  ((build)) && scripts/bootstrap.sh
  exec ctest --test-dir "${LIDARSIM_BUILD_DIR:-build}" --output-on-failure -L long --timeout 3600
fi

packages=(python3-torch python3-h5py libopenblas0-openmp)
scripts/install_packages.sh bench "${packages[@]}"
# Say which BLAS torch will get (the alternative libopenblas0-openmp registers at priority 95).
blas=unknown
if command -v update-alternatives >/dev/null; then
  blas=$(update-alternatives --query libblas.so.3-x86_64-linux-gnu 2>/dev/null | sed -n 's/^Value: //p')
  echo "bench: libblas.so.3 -> ${blas:-unknown}" >&2
fi

build_dir=${LIDARSIM_BUILD_DIR:-build}
out=${out:-$build_dir/bench-results}
mkdir -p "$out"
export OMP_WAIT_POLICY=${OMP_WAIT_POLICY:-passive}
if ((build)); then
  cmake -S . -B "$build_dir" -DCMAKE_BUILD_TYPE=${CMAKE_BUILD_TYPE:-Release} -DLIDARSIM_BENCH=ON >/dev/null  # scripts/test.sh turns them off
  targets=(bench_unet_vs_torch bench_pipeline)
  ((growth)) && targets+=(bench_growth)
  cmake --build "$build_dir" --target "${targets[@]}" -j"$(nproc)"
fi

load_before=$(cut -d' ' -f1-3 /proc/loadavg)
for ((round = 1; round <= rounds; round++)); do
  echo "bench: round $round of $rounds" >&2
  mkdir -p "$out/round$round"
  "$build_dir/bench/bench_unet_vs_torch" --python /usr/bin/python3 --reps "$reps" \
    --json "$out/round$round/unet_vs_torch.json" "${extra[@]}"
  # whole: UNet on every frame, no outputs; outputs: the `lidar-infer sim --every 10` loop.
  "$build_dir/bench/bench_pipeline" --runs "$runs" --only whole,objects,outputs \
    --json "$out/round$round/pipeline.json"
done
if ((growth)); then
  "$build_dir/bench/bench_growth" --png docs/growth.png --json "$out/growth.json"
fi
load_after=$(cut -d' ' -f1-3 /proc/loadavg)

cpu=$(lscpu 2>/dev/null | sed -n 's/^Model name: *//p' | head -1)
# The vector extensions the kernels can be chosen by (nn/cpu_features.h), and the level forced, if any.
flags=$(grep -m1 '^flags' /proc/cpuinfo 2>/dev/null | tr ' ' '\n' |
  grep -xE 'avx2|fma|avx512f|avx512bw|avx512vl|avx512dq|avx512_bf16|amx_bf16|amx_tile' | tr '\n' ' ' | sed 's/ $//') || flags=""
isa="${LIDARSIM_ISA:-auto}"
# The CPU kind a table is kept per: vendor, family and model as /proc/cpuinfo gives them.
cpu_key=$(awk -F': *' '/^vendor_id/ {v=$2} /^cpu family/ {f=$2} /^model[ \t]*:/ {m=$2} END {print v "-" f "-" m}' /proc/cpuinfo 2>/dev/null) || cpu_key=unknown
python3 - "$out" "$rounds" "$growth" "$write_readme" "$cpu" "$(nproc)" "$load_before" "$load_after" "$blas" "$flags" "$isa" "$write_docs" "$cpu_key" <<'PY'
import json, os, sys, datetime, statistics
out, rounds, growth, write_readme, cpu, ncpu, load_before, load_after, blas, flags, isa, write_docs, cpu_key = sys.argv[1:]
rounds = int(rounds)
us = [json.load(open(os.path.join(out, f"round{i}", "unet_vs_torch.json"))) for i in range(1, rounds + 1)]
ps = [json.load(open(os.path.join(out, f"round{i}", "pipeline.json"))) for i in range(1, rounds + 1)]
med = statistics.median
names = {"train_b1": "training step, batch 1", "train_b4": "training step, batch 4",
         "infer_b1": "inference, batch 1", "infer_b4": "inference, batch 4",
         "infer_b1_bf16": "inference in bf16 (peer: its fp32), batch 1",
         "infer_b4_bf16": "inference in bf16 (peer: its fp32), batch 4"}
# The bf16 rows twice more: against the peer's own bf16 (torch.autocast) and against our fp32.
bf16_against = {"infer_b1_bf16": "infer_b1", "infer_b4_bf16": "infer_b4"}
u = us[0]
torch = u.get("torch") or {}
lines = []
lines.append(f"Measured by `scripts/bench.sh` on {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC: "
             f"{cpu or 'unknown CPU'} (flags: {flags or 'unknown'}; LIDARSIM_ISA={isa}), {ncpu} online CPUs, "
             f"{u['threads']} threads, load average {load_before} before and "
             f"{load_after} after. Peer: PyTorch {torch.get('torch_version', '?')} in the same run (fastest of its "
             f"settings and OpenMP wait policies per row; libblas.so.3 -> {blas}). Each figure is the median of {rounds} rounds; a round "
             f"takes the median of {u['reps']} repetitions (engine) and {ps[0]['runs']} runs (pipeline). Ratios: the "
             f"median of the rounds' ratios (each round times ours and PyTorch back to back), their range in brackets.")
lines.append("")
lines.append(f"| row ({u['rows']} x {u['cols']}) | ours | PyTorch | ours / PyTorch | our GFLOP/s |")
lines.append("|---|---:|---:|---:|---:|")
for r in u["table"]:
    rows = [next(x for x in ui["table"] if x["row"] == r["row"]) for ui in us]
    ours = med([x["ours_s"] for x in rows])
    gflops = med([x["ours_gflops"] for x in rows])
    if r.get("torch_s"):
        ratios = [x["ratio"] for x in rows]
        peer = f"{med([x['torch_s'] for x in rows]):.3f} s"
        ratio = f"**{med(ratios):.2f}** ({min(ratios):.2f}–{max(ratios):.2f})"
    else:
        peer, ratio = "–", "–"
    lines.append(f"| unet-ref {names.get(r['row'], r['row'])} | {ours:.3f} s | {peer} | {ratio} | {gflops:.0f} |")
    if r["row"] in bf16_against and all(x.get("torch_bf16_s") for x in rows):
        ratios = [x["ours_s"] / x["torch_bf16_s"] for x in rows]
        lines.append(f"| unet-ref inference in bf16 (peer: its bf16 autocast), batch {r['row'][7]} | {ours:.3f} s | "
                     f"{med([x['torch_bf16_s'] for x in rows]):.3f} s | **{med(ratios):.2f}** ({min(ratios):.2f}–{max(ratios):.2f}) | |")
    if r["row"] in bf16_against:
        fp32 = [next(x for x in ui["table"] if x["row"] == bf16_against[r["row"]]) for ui in us]
        ratios = [b["ours_s"] / f["ours_s"] for b, f in zip(rows, fp32)]
        lines.append(f"| unet-ref inference in bf16 against our fp32, batch {r['row'][7]} | {ours:.3f} s | "
                     f"{med([f['ours_s'] for f in fp32]):.3f} s (ours, fp32) | **{med(ratios):.2f}** ({min(ratios):.2f}–{max(ratios):.2f}) | |")
w = {k: med([p["whole"][k] for p in ps]) for k in ("fps",)}
w0 = ps[0]["whole"]
unet_ms = med([p["whole"]["stage_ms"]["unet"] for p in ps])
pcl_ms = med([p["whole"]["stage_ms"]["pcl_generator"] for p in ps])
lines.append(f"| whole pipeline, 64 x 1024, UNet base {w0['unet_base']} depth {w0['unet_depth']} ({w0['model']}) on every frame, no outputs | "
             f"{w['fps']:.1f} frames/s ({unet_ms:.1f} ms UNet, {pcl_ms:.1f} ms PCL generator) | – | – | |")
o = ps[0]["outputs"]
loop_fps = med([p["outputs"]["loop_fps"] for p in ps])
loop_bound = med([p["outputs"]["fps_cpu_bound"] for p in ps])
lines.append(f"| `lidar-infer sim --every {o['every']}` loop (outputs of every {o['every']}th frame written, UNet on those) | "
             f"{loop_fps:.0f} frames/s wall (<= {loop_bound:.0f} from CPU time) | – | – | |")
ob = ps[0]["objects"]
stage = lambda k: 1000 * med([p["objects"]["stage_ms"][k] for p in ps])
lines.append(f"| object-level model, {ob['count']} objects | {med([p['objects']['fps'] for p in ps]):.0f} frames/s wall "
             f"({med([p['objects']['fps_cpu_bound'] for p in ps]):.0f} from CPU time; occlusion {stage('occlusion'):.0f} µs, "
             f"tracking {stage('tracking'):.0f} µs, KPI {stage('kpi'):.0f} µs) | – | – | |")
if growth == "1":
    g = json.load(open(os.path.join(out, "growth.json")))
    for s in g["series"]:
        lines.append(f"| growth: {s['name']} against {s['size']} ({', '.join(str(int(x)) for x in s['sizes'])}) | "
                     f"exponent {s['exponent']:.2f} | – | – | {s['verdict']} |")
table = "\n".join(lines)
print()
print(table)
if write_readme == "1":
    begin, end = "<!-- bench.sh table: begin -->", "<!-- bench.sh table: end -->"
    text = open("README.md").read()
    if begin not in text or end not in text:
        sys.exit("bench.sh: README.md has no bench.sh table markers")
    head, rest = text.split(begin, 1)
    _, tail = rest.split(end, 1)
    tmp = "README.md.bench-tmp"
    open(tmp, "w").write(head + begin + "\n" + table + "\n" + end + tail)
    os.replace(tmp, "README.md")
    print("bench.sh: README.md table updated", file=sys.stderr)
if write_docs == "1":
    doc, end_all = "docs/performance.md", "<!-- bench.sh cpu tables: end -->"
    begin, end = f"<!-- bench.sh cpu {cpu_key}: begin -->", f"<!-- bench.sh cpu {cpu_key}: end -->"
    text = open(doc).read()
    if end_all not in text:
        sys.exit(f"bench.sh: {doc} has no '{end_all}' marker")
    parts = cpu_key.split("-")
    kind = f"{parts[0]} family {parts[1]} model {parts[2]}" if len(parts) == 3 else cpu_key
    section = f"{begin}\n### {cpu or 'unknown CPU'} ({kind})\n\n{table}\n{end}"
    if begin in text and end in text:
        head, rest = text.split(begin, 1)
        text = head + section + rest.split(end, 1)[1]
    else:
        text = text.replace(end_all, section + "\n\n" + end_all)
    tmp = doc + ".bench-tmp"
    open(tmp, "w").write(text)
    os.replace(tmp, doc)
    print(f"bench.sh: {doc} table for {cpu_key} updated", file=sys.stderr)
PY
