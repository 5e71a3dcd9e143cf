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
#include <array>
#include <atomic>
#include <cstdint>
#include <type_traits>
#include <utility>

namespace lidarsim::nn::detail {

// Runs call(ctx, tid, nt) on nt threads, the caller being tid 0; nt is 1 when !enable. When
// given, prepare(ctx, nt) runs first, on the caller, once nt is known.
void run_team(void (*call)(void*, int, int), void* ctx, bool enable, void (*prepare)(void*, int) = nullptr);

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

// Items [0, n) shared by a team for loops whose items write disjoint outputs (who runs an item
// does not change the result): each thread runs its schedule(static) share in order, and one
// that finishes early takes the last items of the others' shares. The two threads of a step do
// not run at the same speed (the first was 4-10 % slower on the same work, measured), and a
// static split left the faster one waiting at the end of every region.
class Shares {
 public:
  static constexpr int kMaxThreads = 64;  // more threads: plain static shares
  explicit Shares(long n) : n_(n) {}
  // Before the team starts (run_team's prepare): blocks of items, about 16 per thread.
  void init(int nt) {
    nt_ = nt;
    grain_ = std::max(1L, n_ / (16L * nt));
    const long blocks = (n_ + grain_ - 1) / grain_;
    if (nt > kMaxThreads) return;
    for (int t = 0; t < nt; ++t) {
      const auto [b, e] = static_range(blocks, t, nt);
      slots_[t].v.store(pack(b, e), std::memory_order_relaxed);
    }
  }
  // body(i) over this thread's share, then over what is left of the others'.
  template <typename F>
  void run(int tid, int nt, F&& body) {
    if (nt > kMaxThreads || nt != nt_) {  // (nt_ differs only if init was skipped: run serially)
      const auto [b, e] = static_range(n_, tid, nt);
      for (long i = b; i < e; ++i) body(i);
      return;
    }
    for (int k = 0; k < nt; ++k) {
      std::atomic<std::uint64_t>& slot = slots_[(tid + k) % nt].v;
      const bool own = k == 0;  // the owner takes from the front, others from the back
      for (std::uint64_t v = slot.load(std::memory_order_relaxed);;) {
        const long f = static_cast<long>(v & 0xffffffffu), e = static_cast<long>(v >> 32);
        if (f >= e) break;
        const long blk = own ? f : e - 1;
        if (!slot.compare_exchange_weak(v, own ? pack(f + 1, e) : pack(f, e - 1), std::memory_order_relaxed))
          continue;
        const long i_end = std::min(n_, (blk + 1) * grain_);
        for (long i = blk * grain_; i < i_end; ++i) body(i);
        v = slot.load(std::memory_order_relaxed);
      }
    }
  }

 private:
  static std::uint64_t pack(long f, long e) {
    return static_cast<std::uint64_t>(f) | static_cast<std::uint64_t>(e) << 32;
  }
  struct alignas(64) Slot {
    std::atomic<std::uint64_t> v{0};
  };
  long n_;
  int nt_ = 0;
  long grain_ = 1;
  std::array<Slot, kMaxThreads> slots_;
};

// body(tid, nt, shares) on the team, with shares of [0, n) set up for it (see Shares).
template <typename F>
void parallel_shared(long n, bool enable, F&& body) {
  struct Ctx {
    Shares shares;
    std::remove_reference_t<F>* body;
  };
  Ctx ctx{Shares(n), &body};
  run_team(
      [](void* c, int tid, int nt) {
        Ctx* x = static_cast<Ctx*>(c);
        (*x->body)(tid, nt, x->shares);
      },
      &ctx, enable, [](void* c, int nt) { static_cast<Ctx*>(c)->shares.init(nt); });
}

// body(i) for i in [0, n), each exactly once, balanced between the threads (see Shares): for
// loops whose items write disjoint outputs.
template <typename F>
void parallel_for(long n, bool enable, F&& body) {
  if (n <= 0) return;
  parallel_shared(n, enable, [&](int tid, int nt, Shares& shares) { shares.run(tid, nt, body); });
}

}  // namespace lidarsim::nn::detail
