#include "sensor/kpi_noise.h"

#include <algorithm>
#include <cmath>

#include "common/counter_hash.h"

namespace lidarsim::sensor {

namespace {
// SplitMix64 as a generator: advances the state x and returns the next output.
std::uint64_t next_splitmix(std::uint64_t& x) { return mix64(x += kSplitMixGamma); }
std::uint64_t rotl(std::uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }
}  // namespace

KpiRng::KpiRng(std::uint64_t seed) {
  for (auto& w : s_) w = next_splitmix(seed);
}

KpiRng KpiRng::stream(std::uint64_t seed, std::uint64_t a, std::uint64_t b, std::uint64_t purpose) {
  std::uint64_t h = seed;
  std::uint64_t k = next_splitmix(h);
  for (std::uint64_t v : {a, b, purpose}) {
    h = k ^ v;
    k = next_splitmix(h);
  }
  return KpiRng(k);
}

KpiRng::result_type KpiRng::operator()() {
  const std::uint64_t r = rotl(s_[1] * 5, 7) * 9;
  const std::uint64_t t = s_[1] << 17;
  s_[2] ^= s_[0];
  s_[3] ^= s_[1];
  s_[1] ^= s_[2];
  s_[0] ^= s_[3];
  s_[2] ^= t;
  s_[3] = rotl(s_[3], 45);
  return r;
}

double kpi_normal(KpiRng& rng) {
  double x, y, r2;
  do {
    x = 2.0 * kpi_uniform(rng) - 1.0;
    y = 2.0 * kpi_uniform(rng) - 1.0;
    r2 = x * x + y * y;
  } while (r2 > 1.0 || r2 == 0.0);
  const double mult = std::sqrt(-2 * std::log(r2) / r2);
  return y * mult;  // * stddev 1 + mean 0: unchanged
}

InnovationSampler::InnovationSampler(const Innovation& innovation) : in(innovation) {
  if (in.type == Innovation::Type::Mixture) {
    const double p = in.outlier_probability, r = in.outlier_scale;
    s_core = 1 / std::sqrt((1 - p) + p * r * r);
    s_wide = s_core * r;
  }
}

double InnovationSampler::operator()(KpiRng& rng) const {
  switch (in.type) {
    case Innovation::Type::Gaussian: return kpi_normal(rng);
    case Innovation::Type::Mixture: {
      const double s = kpi_uniform(rng) < in.outlier_probability ? s_wide : s_core;
      return s * kpi_normal(rng);
    }
    case Innovation::Type::StudentT: break;
  }
  return sample_innovation(in, rng);
}

double sample_innovation(const Innovation& in, KpiRng& rng) {
  std::normal_distribution<double> normal(0.0, 1.0);
  switch (in.type) {
    case Innovation::Type::Gaussian: return normal(rng);
    case Innovation::Type::StudentT: {
      // t = N / sqrt(chi2_dof / dof); variance dof / (dof - 2), scaled back to 1.
      std::chi_squared_distribution<double> chi2(in.dof);
      const double t = normal(rng) / std::sqrt(chi2(rng) / in.dof);
      return t * std::sqrt((in.dof - 2) / in.dof);
    }
    case Innovation::Type::Mixture: {
      const double p = in.outlier_probability, r = in.outlier_scale;
      const double s_core = 1 / std::sqrt((1 - p) + p * r * r);  // unit total variance
      std::uniform_real_distribution<double> u(0.0, 1.0);
      const double s = u(rng) < p ? s_core * r : s_core;
      return s * normal(rng);
    }
  }
  return normal(rng);
}

double ar1_step(double z, double rho, int gap, double eps) {
  const double a = gap == 1 ? rho : std::pow(rho, gap);
  return a * z + std::sqrt(std::max(0.0, 1 - a * a)) * eps;
}

bool BurstChain::step(double rate, double burst_mean, KpiRng& rng) {
  const auto u = [](KpiRng& r) { return kpi_uniform(r); };
  rate = std::clamp(rate, 0.0, 1.0);
  if (!started) {  // start from the stationary distribution
    started = true;
    on = u(rng) < rate;
    return on;
  }
  if (rate <= 0) return on = false;
  if (rate >= 1) return on = true;
  double leave = 1 / std::max(1.0, burst_mean);      // on -> off
  double enter = rate * leave / (1 - rate);           // off -> on, stationary rate = rate
  if (enter > 1) {
    enter = 1;
    leave = (1 - rate) / rate;
  }
  on = on ? !(u(rng) < leave) : (u(rng) < enter);
  return on;
}

double RunningTargetController::running_std() const { return std::sqrt(std::max(0.0, v_)); }

double RunningTargetController::apply(double z) {
  const double out = cfg_.enabled ? g_ * z + c_ : z;
  const double a = a_;
  const double d = out - m_;
  m_ += a * d;
  v_ += a * (d * (out - m_) - v_);
  if (cfg_.enabled) {
    c_ -= cfg_.mean_gain * m_;
    // On the variance, not the std: E[sqrt(v)] < 1 at unit variance (Jensen, strongly so for
    // heavy tails), so a std target would inflate the injected spread.
    g_ = std::clamp(g_ * std::exp(-0.5 * cfg_.std_gain * (v_ - 1)), 0.2, 5.0);
  }
  return out;
}

}  // namespace lidarsim::sensor
