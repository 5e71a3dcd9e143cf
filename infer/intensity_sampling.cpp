#include "infer/intensity_sampling.h"

#include <algorithm>
#include <cmath>

#include "common/counter_hash.h"
#include "common/error.h"

namespace lidarsim::infer {
namespace {

// (0, 1) from the top 53 bits, never 0 or 1 (the inverse CDFs below take logs).
double to_unit(std::uint64_t bits) { return (static_cast<double>(bits >> 11) + 0.5) * 0x1.0p-53; }

}  // namespace

void cell_uniforms(std::uint64_t seed, std::uint64_t frame, std::uint64_t cell, double& u1, double& u2) {
  const std::uint64_t key = splitmix64(splitmix64(splitmix64(seed) ^ frame) ^ cell);
  u1 = to_unit(splitmix64(key ^ 0x1ull));
  u2 = to_unit(splitmix64(key ^ 0x2ull));
}

bool draws_zero(double p_zero, const IntensitySampling& s, std::uint64_t frame, std::uint64_t cell) {
  const std::uint64_t key = splitmix64(splitmix64(splitmix64(s.seed) ^ frame) ^ cell);
  return to_unit(splitmix64(key ^ 0x3ull)) < p_zero;
}

float sample_intensity(nn::HeadKind spread, float mean, float scale, const IntensitySampling& s, std::uint64_t frame,
                       std::uint64_t cell) {
  double u1 = 0, u2 = 0;
  cell_uniforms(s.seed, frame, cell, u1, u2);
  double noise = 0;
  if (spread == nn::HeadKind::log_scale_laplace) {
    // Inverse CDF of Laplace(0, b): -b sign(u - 1/2) log(1 - 2 |u - 1/2|).
    const double d = u1 - 0.5;
    noise = -scale * (d < 0 ? -1.0 : 1.0) * std::log(1 - 2 * std::abs(d));
  } else if (spread == nn::HeadKind::log_scale_gaussian) {
    noise = scale * std::sqrt(-2 * std::log(u1)) * std::cos(2 * M_PI * u2);  // Box-Muller
  } else {
    throw Error("sample_intensity: not a spread head");
  }
  return static_cast<float>(std::clamp(mean + noise, static_cast<double>(s.min), static_cast<double>(s.max)));
}

float sample_intensity_empirical(const nn::SpreadResidual& residual, float mean, float scale,
                                 const IntensitySampling& s, std::uint64_t frame, std::uint64_t cell) {
  if (residual.empty()) throw Error("sample_intensity_empirical: no residual table");
  double u1 = 0, u2 = 0;
  cell_uniforms(s.seed, frame, cell, u1, u2);
  const double lo = s.min, hi = s.max;
  double v = std::clamp(mean + scale * residual.quantile(mean, u1), lo, hi);
  if (const double step = residual.target_step; step > 0) {
    // k / n for a grid of 1/n (0.01, 1/255): the same float a sensor file holds for that value,
    // which k * step, with the step stored as a float, misses by an ulp at times.
    const double n = std::round(1 / step);
    const double k = std::round((v - lo) / step);
    v = std::clamp(lo + (std::abs(n * step - 1) < 1e-4 ? k / n : k * step), lo, hi);
  }
  return static_cast<float>(v);
}

}  // namespace lidarsim::infer
