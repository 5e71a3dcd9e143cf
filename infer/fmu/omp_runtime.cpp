// The part of the OpenMP runtime (libgomp's ABI) the model's code calls, on the engine's thread
// team (nn/parallel.h), so lidarsim_osi_model.so needs no libgomp.so. GCC's libgomp.a cannot be
// linked into a shared object: it uses local-exec TLS (R_X86_64_TPOFF32 against gomp_tls_data).
//
// What the model's objects import (nm -u; the link fails with --no-undefined if that grows):
// GOMP_parallel (`#pragma omp parallel [for]`), GOMP_loop_nonmonotonic_dynamic_start/next and
// GOMP_loop_end_nowait (`schedule(dynamic, c)`), omp_get_thread_num/num_threads (static
// schedules are split inline from these), omp_get_max_threads and omp_in_parallel.
// Semantics kept: the team size is OMP_NUM_THREADS (its first entry) or the CPUs this process may
// run on; a region inside a region runs on one thread (OpenMP's default without nesting); every
// thread of a region ends it together (the caller returns after all of them, the implicit
// barrier). Reductions are compiled to atomics and need nothing here.
#include <sched.h>

#include <algorithm>
#include <atomic>
#include <cstdlib>
#include <deque>
#include <mutex>
#include <thread>

#include "nn/parallel.h"

namespace {

// One `for` of a region, shared by its threads: the next unclaimed iteration.
struct WorkShare {
  long end, incr, chunk;
  std::atomic<long> next;
  WorkShare(long start, long e, long i, long c) : end(e), incr(i), chunk(c), next(start) {}
};

struct Region {
  std::mutex mutex;
  std::deque<WorkShare> shares;  // in the order the region's threads meet them (deque: stable)
};

struct ThreadState {
  Region* region = nullptr;  // null outside a region (and in a region of one thread)
  int tid = 0, nt = 1;
  std::size_t shares_met = 0;
  WorkShare* current = nullptr;
};
thread_local ThreadState t_omp;
thread_local WorkShare t_serial{0, 0, 1, 1};  // the loop of a one-thread region

int default_threads() {
  if (const char* env = std::getenv("OMP_NUM_THREADS"); env && *env) {
    char* end = nullptr;
    const long v = std::strtol(env, &end, 10);
    if (v > 0 && (*end == '\0' || *end == ',')) return static_cast<int>(v);
  }
  cpu_set_t set;
  if (sched_getaffinity(0, sizeof set, &set) == 0 && CPU_COUNT(&set) > 0) return CPU_COUNT(&set);
  return std::max(1u, std::thread::hardware_concurrency());
}

bool claim(WorkShare& ws, long* istart, long* iend) {
  const long step = ws.chunk * ws.incr;
  const long begin = ws.next.fetch_add(step, std::memory_order_relaxed);
  if (ws.incr > 0 ? begin >= ws.end : begin <= ws.end) return false;
  *istart = begin;
  *iend = ws.incr > 0 ? (ws.end - begin < step ? ws.end : begin + step) : (ws.end - begin > step ? ws.end : begin + step);
  return true;
}

}  // namespace

extern "C" {

int omp_get_max_threads() {
  static const int n = default_threads();
  return n;
}
int omp_get_num_threads() { return t_omp.nt; }
int omp_get_thread_num() { return t_omp.tid; }
int omp_in_parallel() { return t_omp.nt > 1; }

void GOMP_parallel(void (*fn)(void*), void* data, unsigned num_threads, unsigned /*flags*/) {
  struct Ctx {
    void (*fn)(void*);
    void* data;
    Region region;
  } ctx{fn, data, {}};
  // num_threads 1: an if() clause that is false. A region inside a region: one thread. Other
  // num_threads clauses get the team's size (the model's code has none).
  const bool enable = num_threads != 1 && t_omp.nt == 1;
  lidarsim::nn::detail::run_team(
      [](void* c, int tid, int nt) {
        Ctx& x = *static_cast<Ctx*>(c);
        const ThreadState outer = t_omp;
        t_omp = ThreadState{nt > 1 ? &x.region : nullptr, tid, nt, 0, nullptr};
        x.fn(x.data);
        t_omp = outer;
      },
      &ctx, enable);
}

bool GOMP_loop_nonmonotonic_dynamic_start(long start, long end, long incr, long chunk, long* istart, long* iend) {
  ThreadState& t = t_omp;
  if (!t.region) {
    t_serial.end = end;
    t_serial.incr = incr;
    t_serial.chunk = chunk;
    t_serial.next.store(start, std::memory_order_relaxed);
    t.current = &t_serial;
  } else {
    std::lock_guard<std::mutex> lock(t.region->mutex);
    if (t.region->shares.size() <= t.shares_met) t.region->shares.emplace_back(start, end, incr, chunk);
    t.current = &t.region->shares[t.shares_met++];
  }
  return claim(*t.current, istart, iend);
}

bool GOMP_loop_nonmonotonic_dynamic_next(long* istart, long* iend) { return claim(*t_omp.current, istart, iend); }

void GOMP_loop_end_nowait() { t_omp.current = nullptr; }

}  // extern "C"
