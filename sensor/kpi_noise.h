#pragma once
// Building blocks of the KPI manager's noise: heavy-tailed unit-variance innovations, an AR(1)
// step, a two-state Markov chain for bursty events (misses, heading flips), and the discrete
// feedback controller that keeps the running mean and spread of an injected signal on target.
#include <cstdint>
#include <random>

#include "sensor/kpi_model.h"

namespace lidarsim::sensor {

// A small, fast engine (xoshiro256**, 32 bytes of state) so every track can own several
// streams. Seeded through splitmix64, so nearby seeds give unrelated streams.
class KpiRng {
 public:
  using result_type = std::uint64_t;
  // Not explicit without a seed: arrays of streams in aggregates are value-initialised (clang
  // refuses an explicit default constructor there; the fuzz build uses clang).
  KpiRng() : KpiRng(1) {}
  explicit KpiRng(std::uint64_t seed);
  // A stream keyed by (seed, a, b, purpose): the KPI manager gives each track and each draw
  // purpose its own, so a change in how many draws one target takes (another innovation type,
  // a term on one class) leaves every other target's and track's draws unchanged (common
  // random numbers between model variants).
  static KpiRng stream(std::uint64_t seed, std::uint64_t a, std::uint64_t b, std::uint64_t purpose);
  static constexpr result_type min() { return 0; }
  static constexpr result_type max() { return ~result_type{0}; }
  result_type operator()();

 private:
  std::uint64_t s_[4];
};

// One draw with mean 0 and variance 1 from the innovation distribution.
double sample_innovation(const Innovation& in, KpiRng& rng);

// AR(1) with unit stationary variance: z <- rho^gap z + sqrt(1 - rho^(2 gap)) eps. A gap of
// several frames (an object that was absent) is one step with rho^gap, so the law is the same.
double ar1_step(double z, double rho, int gap, double eps);

// Two states (off, on). From off it turns on with probability q, from on it turns off with
// probability 1 / burst_mean, so runs of "on" last burst_mean frames on average and q is set so
// the stationary "on" rate equals `rate`: q = rate / ((1 - rate) burst_mean). When that would
// need q > 1 the runs are lengthened instead, so the rate still holds.
struct BurstChain {
  bool on = false;
  bool started = false;
  bool step(double rate, double burst_mean, KpiRng& rng);
};

// Discrete feedback controller on a standardized signal (target mean 0, std 1): out = g z + c.
// Running mean m and variance v of `out` are exponentially weighted over `window` samples;
// each sample the offset integrates the mean error (c -= mean_gain m) and the gain is corrected
// multiplicatively on the spread (g *= exp(-std_gain (v - 1) / 2)), bounded to [0.2, 5].
class RunningTargetController {
 public:
  explicit RunningTargetController(ControllerConfig cfg = {}) : cfg_(cfg) {}
  double apply(double z);
  double offset() const { return c_; }
  double gain() const { return g_; }
  double running_mean() const { return m_; }
  double running_std() const;

 private:
  ControllerConfig cfg_;
  double c_ = 0, g_ = 1, m_ = 0, v_ = 1;
};

}  // namespace lidarsim::sensor
