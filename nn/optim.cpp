#include "nn/optim.h"

#include <cmath>

#include "common/error.h"
#include "nn/parallel.h"

namespace lidarsim::nn {

using detail::parallel_for;
using detail::parallel_ranges;

std::string to_string(OptimizerKind kind) {
  const int k = static_cast<int>(kind);
  if (k < 0 || k >= kOptimizerKinds) throw Error("optimizer: kind: not an OptimizerKind (" + std::to_string(k) + ")");
  return kOptimizerKindNames[k];
}

std::optional<OptimizerKind> optimizer_kind_from_string(const std::string& name) {
  for (int k = 0; k < kOptimizerKinds; ++k)
    if (name == kOptimizerKindNames[k]) return static_cast<OptimizerKind>(k);
  return std::nullopt;
}

Optimizer::Optimizer(const OptimizerConfig& config, std::size_t num_params) : config_(config) {
  to_string(config_.kind);  // throws for a value outside the enum (a cast from a bad integer)
  if (!std::isfinite(config_.lr) || config_.lr <= 0)
    throw Error("optimizer: lr: expected a finite value > 0, got " + std::to_string(config_.lr));
  m_.assign(num_params, 0.f);
  v_.assign(num_params, 0.f);  // unused by SGD; kept so checkpoints have one layout
}

void Optimizer::step(ParamArena& params) {
  const std::size_t n = params.size();
  if (m_.size() != n)
    throw Error("optimizer: state: expected " + std::to_string(n) + " values, got " + std::to_string(m_.size()));
  float* p = params.values();
  float* g = params.grads();
  ++steps_;

  if (config_.clip_norm > 0) {
    // Global L2 norm in double over fixed chunks summed in order: the same for any thread count.
    constexpr std::size_t kChunk = 1 << 14;
    const std::size_t chunks = (n + kChunk - 1) / kChunk;
    std::vector<double> partial(chunks, 0.0);
    parallel_for(static_cast<long>(chunks), n > (1u << 15), [&](long c) {
      double s = 0;
      for (std::size_t i = c * kChunk; i < std::min(n, (c + 1) * kChunk); ++i) s += double(g[i]) * g[i];
      partial[c] = s;
    });
    double total = 0;
    for (double s : partial) total += s;
    const double norm = std::sqrt(total);
    // torch.nn.utils.clip_grad_norm_: scale by max_norm / (norm + 1e-6) when that is < 1.
    const double coef = config_.clip_norm / (norm + 1e-6);
    if (coef < 1.0) {
      const float c = static_cast<float>(coef);
      parallel_ranges(static_cast<long>(n), n > (1u << 15), [&](long b, long e) {
#pragma omp simd
        for (long i = b; i < e; ++i) g[i] *= c;
      });
    }
  }

  // Per-element step factor: 1 except for parameters registered with an lr_scale (few values).
  // The arena's layout is fixed once built, so the table is filled on the first step only.
  if (scale_.size() != n) {
    scale_.assign(n, 1.f);
    for (const ParamInfo& info : params.infos())
      if (info.lr_scale != 1.f) std::fill_n(scale_.begin() + static_cast<std::ptrdiff_t>(info.offset), info.shape.numel(), info.lr_scale);
  }
  const float* sc = scale_.data();

  float* m = m_.data();
  if (config_.kind == OptimizerKind::Sgd) {
    // torch.optim.SGD, dampening 0, no Nesterov: buf = momentum buf + g (buf = g at step 1).
    const float mu = config_.momentum, lr = config_.lr;
    parallel_ranges(static_cast<long>(n), n > (1u << 15), [&](long b, long e) {
#pragma omp simd
      for (long i = b; i < e; ++i) {
        m[i] = mu * m[i] + g[i];
        p[i] -= sc[i] * lr * m[i];
      }
    });
    return;
  }
  // torch.optim.Adam (single-tensor path): scalars in double, tensor math in float.
  float* v = v_.data();
  const double t = static_cast<double>(steps_);
  const double bc1 = 1.0 - std::pow(static_cast<double>(config_.beta1), t);
  const double bc2 = 1.0 - std::pow(static_cast<double>(config_.beta2), t);
  const float step_size = static_cast<float>(config_.lr / bc1);
  const float bc2_sqrt = static_cast<float>(std::sqrt(bc2));
  const float b1 = config_.beta1, b2 = config_.beta2, eps = config_.eps;
  const float one_b1 = 1.f - b1, one_b2 = 1.f - b2;
  parallel_ranges(static_cast<long>(n), n > (1u << 15), [&](long b, long e) {
#pragma omp simd
    for (long i = b; i < e; ++i) {
      m[i] = b1 * m[i] + one_b1 * g[i];
      v[i] = b2 * v[i] + one_b2 * g[i] * g[i];
      const float denom = std::sqrt(v[i]) / bc2_sqrt + eps;
      p[i] -= sc[i] * step_size * (m[i] / denom);
    }
  });
}

}  // namespace lidarsim::nn
