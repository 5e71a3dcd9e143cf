#pragma once
// The engine's thread team: what `#pragma omp parallel` did in nn/, minus the cost that made a
// training step scale badly on two cores. Under OMP_WAIT_POLICY=passive (which this project sets:
// spinning OpenMP barriers cost 2-40x on a busy machine) every one of a step's ~200 parallel
// regions woke a sleeping worker through the kernel and then slept again at its end. Here the
// workers spin for a short while (LIDARSIM_SPIN_US, default 100 us) after each task before they
// sleep, so back-to-back regions start without a wake-up, and a busy machine loses at most that
// much CPU per region.
//
// Team size: omp_get_max_threads() (OMP_NUM_THREADS, omp_set_num_threads). Calls made inside a
// team task, inside an OpenMP region, or while another thread uses the team run serially (as
// OpenMP's nested regions do by default).
#include <algorithm>
#include <type_traits>
#include <utility>

namespace lidarsim::nn::detail {

// Runs call(ctx, tid, nt) on nt threads, the caller being tid 0; nt is 1 when !enable.
void run_team(void (*call)(void*, int, int), void* ctx, bool enable);

// The number of threads a run_team would use now.
int team_threads();

// Runs body(tid, nt) on the team (body must not throw on a worker thread).
template <typename F>
void parallel(bool enable, F&& body) {
  using B = std::remove_reference_t<F>;
  run_team([](void* ctx, int tid, int nt) { (*static_cast<B*>(ctx))(tid, nt); },
           const_cast<void*>(static_cast<const void*>(&body)), enable);
}

// OpenMP's schedule(static) split of [0, n) over nt threads: thread tid's [begin, end).
inline std::pair<long, long> static_range(long n, int tid, int nt) {
  long q = n / nt, r = n % nt, begin;
  if (tid < r) {
    ++q;
    begin = q * tid;
  } else {
    begin = q * tid + r;
  }
  return {begin, begin + q};
}

// body(begin, end) on each thread's static share of [0, n).
template <typename F>
void parallel_ranges(long n, bool enable, F&& body) {
  parallel(enable, [&](int tid, int nt) {
    const auto [b, e] = static_range(n, tid, nt);
    if (b < e) body(b, e);
  });
}

// body(i) for i in [0, n), schedule(static).
template <typename F>
void parallel_for(long n, bool enable, F&& body) {
  parallel_ranges(n, enable, [&](long b, long e) {
    for (long i = b; i < e; ++i) body(i);
  });
}

}  // namespace lidarsim::nn::detail
