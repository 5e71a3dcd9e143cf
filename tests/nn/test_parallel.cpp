// The engine's thread team (nn/parallel.h): every index runs exactly once, each thread gets
// OpenMP's schedule(static) share (per-thread partial sums depend on it), a thread that is done
// takes the rest of a slower one's share (Shares), calls from inside a
// task or from a second thread run serially instead of deadlocking, and an exception in the
// caller's share reaches the caller after the workers are done.
#include <gtest/gtest.h>
#include <omp.h>

#include <atomic>
#include <chrono>
#include <stdexcept>
#include <thread>
#include <vector>

#include "nn/parallel.h"

namespace lidarsim::nn {
namespace {

using detail::parallel;
using detail::parallel_for;
using detail::static_range;

// Restores the thread count a test changed.
struct Threads {
  int before = omp_get_max_threads();
  explicit Threads(int n) { omp_set_num_threads(n); }
  ~Threads() { omp_set_num_threads(before); }
};

TEST(Parallel, StaticRangeIsOpenMPsStaticSplit) {
  for (int nt : {1, 2, 3, 5})
    for (long n : {0L, 1L, 2L, 7L, 64L, 100L}) {
      std::vector<int> owner(static_cast<std::size_t>(n), -1);
      Threads threads(nt);
#pragma omp parallel for schedule(static) num_threads(nt)
      for (long i = 0; i < n; ++i) owner[static_cast<std::size_t>(i)] = omp_get_thread_num();
      for (int tid = 0; tid < nt; ++tid) {
        const auto [b, e] = static_range(n, tid, nt);
        for (long i = b; i < e; ++i) EXPECT_EQ(owner[static_cast<std::size_t>(i)], tid) << n << " over " << nt;
      }
      EXPECT_EQ(static_range(n, nt - 1, nt).second, n);
    }
}

TEST(Parallel, EveryIndexRunsOnceOnEveryThreadCount) {
  for (int nt : {1, 2, 3}) {
    Threads threads(nt);
    for (int rep = 0; rep < 200; ++rep) {  // many back-to-back runs: the workers' wait/wake path
      const long n = 1 + rep % 37;
      std::vector<std::atomic<int>> hits(static_cast<std::size_t>(n));
      parallel_for(n, true, [&](long i) { hits[static_cast<std::size_t>(i)].fetch_add(1); });
      for (long i = 0; i < n; ++i) ASSERT_EQ(hits[static_cast<std::size_t>(i)].load(), 1) << i << " of " << n;
    }
  }
}

TEST(Parallel, AFasterThreadTakesTheRestOfASlowerOnesShare) {
  Threads threads(2);
  for (long n : {1L, 2L, 33L, 64L, 1000L, 100000L}) {
    std::vector<std::atomic<int>> hits(static_cast<std::size_t>(n));
    std::vector<int> ran_by(static_cast<std::size_t>(n), -1);
    detail::parallel_shared(n, true, [&](int tid, int nt, detail::Shares& shares) {
      shares.run(tid, nt, [&](long i) {
        if (tid == 0) std::this_thread::sleep_for(std::chrono::microseconds(n < 100 ? 200 : 0));
        hits[static_cast<std::size_t>(i)].fetch_add(1);
        ran_by[static_cast<std::size_t>(i)] = tid;
      });
    });
    for (long i = 0; i < n; ++i) ASSERT_EQ(hits[static_cast<std::size_t>(i)].load(), 1) << i << " of " << n;
    if (n == 64) {  // thread 0 sleeps on each of its 32 items: thread 1 must have taken some
      int stolen = 0;
      for (long i = 0; i < 32; ++i) stolen += ran_by[static_cast<std::size_t>(i)] == 1;
      EXPECT_GT(stolen, 0);
    }
  }
}

TEST(Parallel, UsesTheRequestedThreadsAndRunsSeriallyWhenDisabled) {
  Threads threads(2);
  std::atomic<int> seen_nt{0}, calls{0};
  parallel(true, [&](int, int nt) {
    seen_nt = nt;
    calls.fetch_add(1);
  });
  EXPECT_EQ(seen_nt.load(), 2);
  EXPECT_EQ(calls.load(), 2);
  calls = 0;
  parallel(false, [&](int tid, int nt) {
    EXPECT_EQ(tid, 0);
    EXPECT_EQ(nt, 1);
    calls.fetch_add(1);
  });
  EXPECT_EQ(calls.load(), 1);
}

TEST(Parallel, NestedAndConcurrentCallsRunSerially) {
  Threads threads(2);
  std::atomic<int> inner_nt_max{0}, total{0};
  parallel(true, [&](int, int) {
    parallel(true, [&](int, int nt) {
      int m = inner_nt_max.load();
      while (nt > m && !inner_nt_max.compare_exchange_weak(m, nt)) {
      }
      total.fetch_add(1);
    });
  });
  EXPECT_EQ(inner_nt_max.load(), 1);
  EXPECT_EQ(total.load(), 2);

  // Two caller threads at once: both finish, every index once per caller.
  std::vector<std::atomic<int>> a(1000), b(1000);
  auto work = [](std::vector<std::atomic<int>>& v) {
    for (int rep = 0; rep < 50; ++rep) detail::parallel_for(1000, true, [&](long i) { v[static_cast<std::size_t>(i)]++; });
  };
  std::thread other([&] { work(b); });
  work(a);
  other.join();
  for (int i = 0; i < 1000; ++i) {
    EXPECT_EQ(a[static_cast<std::size_t>(i)].load(), 50);
    EXPECT_EQ(b[static_cast<std::size_t>(i)].load(), 50);
  }
}

TEST(Parallel, AnExceptionInTheCallersShareReachesTheCaller) {
  Threads threads(2);
  std::atomic<int> worker_done{0};
  EXPECT_THROW(parallel(true,
                        [&](int tid, int) {
                          if (tid == 0) throw std::runtime_error("boom");
                          worker_done = 1;
                        }),
               std::runtime_error);
  EXPECT_EQ(worker_done.load(), 1);  // the worker's share finished before the caller went on
  std::atomic<int> calls{0};
  parallel(true, [&](int, int) { calls.fetch_add(1); });  // the team still works
  EXPECT_EQ(calls.load(), 2);
}

}  // namespace
}  // namespace lidarsim::nn
