#!/usr/bin/env bash
# Data-parallel scaling of one training step on this machine: bench_mpi under mpirun with
# N = 1, 2 ranks (1 OpenMP thread each, the same global batch), several runs each; prints the
# median step time, gradient-sum time and the parallel efficiency T1 / (N x TN), with the load
# average before and after (a shared machine skews every number). Extra arguments go to
# bench_mpi (e.g. --batch 4 --cols 1024). Needs a build with LIDARSIM_MPI (scripts/bootstrap.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
build_dir=${LIDARSIM_BUILD_DIR:-build}
runs=${RUNS:-3}
cmake --build "$build_dir" --target bench_mpi -j2 >/dev/null
export OMP_WAIT_POLICY=passive OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
export OMPI_MCA_pml=${OMPI_MCA_pml:-ob1} OMPI_MCA_btl=${OMPI_MCA_btl:-self,vader}  # one machine: shared memory
out=$(mktemp)
echo "load before: $(cut -d' ' -f1-3 /proc/loadavg) on $(nproc) cores" >&2
for n in 1 2; do
  for ((i = 0; i < runs; ++i)); do
    mpirun --oversubscribe -np "$n" "$build_dir/bench/bench_mpi" --threads 1 "$@" | tee -a "$out" >&2
  done
done
echo "load after: $(cut -d' ' -f1-3 /proc/loadavg)" >&2
python3 - "$out" <<'PY'
import json, statistics, sys
rows = [json.loads(l) for l in open(sys.argv[1]) if l.startswith("{")]
by = {}
for r in rows: by.setdefault(r["ranks"], []).append(r)
med = lambda n, k: statistics.median(r[k] for r in by[n])
t1 = med(1, "step_s")
print(f"{'ranks':>5} {'step s':>8} {'compute s':>10} {'sum s':>8} {'GFLOP/s/rank':>12} {'efficiency':>10}  "
      f"(sum alternatives: allgather+sum, reduce+bcast, MPI_Allreduce s)")
for n in sorted(by):
    step = med(n, "step_s")
    print(f"{n:>5} {step:>8.4f} {med(n, 'compute_s'):>10.4f} {med(n, 'sum_rank_order_s'):>8.5f} "
          f"{med(n, 'gflops_per_rank'):>12.2f} {t1 / (n * step):>10.2f}  "
          f"({med(n, 'allgather_sum_s'):.5f}, {med(n, 'reduce_bcast_s'):.5f}, {med(n, 'mpi_allreduce_s'):.5f})")
print(f"params {rows[0]['params']} ({rows[0]['param_mbytes']:.2f} MB), global batch {rows[0]['global_batch']}, "
      f"grid {rows[0]['grid']}, medians of {len(by[1])} runs")
PY
rm -f "$out"
