#include "nn/parallel.h"

#include <omp.h>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <cstdlib>
#include <exception>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "common/error.h"

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#define LIDARSIM_PAUSE() _mm_pause()
#else
#define LIDARSIM_PAUSE() ((void)0)
#endif

namespace lidarsim::nn::detail {

namespace {

using Clock = std::chrono::steady_clock;

long read_spin_us() {
  const char* env = std::getenv("LIDARSIM_SPIN_US");
  if (!env || !*env) return 100;
  char* end = nullptr;
  const long v = std::strtol(env, &end, 10);
  if (*end || v < 0 || v > 1000000)
    throw Error("environment: LIDARSIM_SPIN_US: expected microseconds 0..1000000, got \"" + std::string(env) + "\"");
  return v;
}

// Waits until pred() holds or spin_us pass; returns whether it holds. After a few pauses it
// yields between checks: when the machine is busy and both threads share one core, the
// thread that is waited for gets the core instead of a spinning one.
template <typename P>
bool spin_for(P pred, long spin_us) {
  if (pred()) return true;
  if (spin_us == 0) return false;
  const auto until = Clock::now() + std::chrono::microseconds(spin_us);
  for (int k = 1;; ++k) {
    if (k < 64) {
      LIDARSIM_PAUSE();
    } else {
      std::this_thread::yield();
    }
    if (pred()) return true;
    if ((k & 15) == 0 && Clock::now() > until) return false;
  }
}

thread_local bool t_in_team = false;  // this thread is running a team task

class Team {
 public:
  Team() : spin_us_(read_spin_us()) {}
  ~Team() {
    {
      std::lock_guard<std::mutex> lock(caller_);
      stop_ = true;
      gen_.fetch_add(1, std::memory_order_seq_cst);
      gen_.notify_all();
    }
    for (std::thread& t : workers_) t.join();
  }

  void run(void (*call)(void*, int, int), void* ctx, bool enable, void (*prepare)(void*, int)) {
    const int nt = enable && !t_in_team && !omp_in_parallel() ? omp_get_max_threads() : 1;
    std::unique_lock<std::mutex> lock(caller_, std::defer_lock);
    if (nt <= 1 || !lock.try_lock()) {
      if (prepare) prepare(ctx, 1);
      call(ctx, 0, 1);
      return;
    }
    if (prepare) prepare(ctx, nt);
    while (static_cast<int>(workers_.size()) < nt - 1) {
      // A new worker starts from the current generation: the bump below is its first run.
      const int tid = static_cast<int>(workers_.size()) + 1;
      const std::uint32_t g0 = gen_.load(std::memory_order_relaxed);
      workers_.emplace_back([this, tid, g0] { work(tid, g0); });
    }
    call_ = call;
    ctx_ = ctx;
    nt_ = nt;
    pending_.store(static_cast<int>(workers_.size()), std::memory_order_relaxed);
    gen_.fetch_add(1, std::memory_order_seq_cst);  // publishes call_, ctx_, nt_
    if (sleepers_.load(std::memory_order_seq_cst) > 0) gen_.notify_all();
    std::exception_ptr error;
    t_in_team = true;
    try {
      call(ctx, 0, nt);
    } catch (...) {
      error = std::current_exception();
    }
    t_in_team = false;
    // Wait for the workers (their tasks use ctx, which lives in the caller's frame).
    if (!spin_for([this] { return pending_.load(std::memory_order_acquire) == 0; }, spin_us_)) {
      master_waiting_.store(true, std::memory_order_seq_cst);
      for (int p; (p = pending_.load(std::memory_order_seq_cst)) != 0;) pending_.wait(p, std::memory_order_seq_cst);
      master_waiting_.store(false, std::memory_order_relaxed);
    }
    if (error) std::rethrow_exception(error);
  }

 private:
  void work(int tid, std::uint32_t seen) {
    for (bool spin = true;;) {  // a worker left out of the last run (fewer threads now) sleeps at once
      std::uint32_t g = seen;
      if (!spin_for([&] { return (g = gen_.load(std::memory_order_acquire)) != seen; }, spin ? spin_us_ : 0)) {
        sleepers_.fetch_add(1, std::memory_order_seq_cst);
        while ((g = gen_.load(std::memory_order_seq_cst)) == seen) gen_.wait(seen, std::memory_order_seq_cst);
        sleepers_.fetch_sub(1, std::memory_order_relaxed);
      }
      seen = g;
      if (stop_) return;
      spin = tid < nt_;
      if (spin) {
        t_in_team = true;
        call_(ctx_, tid, nt_);  // an exception here ends the program, as in an OpenMP region
        t_in_team = false;
      }
      if (pending_.fetch_sub(1, std::memory_order_seq_cst) == 1 && master_waiting_.load(std::memory_order_seq_cst))
        pending_.notify_one();
    }
  }

  const long spin_us_;
  std::mutex caller_;  // one caller at a time; others run serially
  std::vector<std::thread> workers_;
  std::atomic<std::uint32_t> gen_{0};  // bumped once per run
  std::atomic<int> sleepers_{0};       // workers blocked in gen_.wait
  std::atomic<int> pending_{0};        // workers not done with the current run
  std::atomic<bool> master_waiting_{false};
  void (*call_)(void*, int, int) = nullptr;
  void* ctx_ = nullptr;
  int nt_ = 1;
  bool stop_ = false;
};

Team& team() {
  static Team t;
  return t;
}

}  // namespace

void run_team(void (*call)(void*, int, int), void* ctx, bool enable, void (*prepare)(void*, int)) {
  team().run(call, ctx, enable, prepare);
}

int team_threads() { return t_in_team || omp_in_parallel() ? 1 : omp_get_max_threads(); }

}  // namespace lidarsim::nn::detail
