#include "nn/loss.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <vector>

#include "common/error.h"
#include "nn/parallel.h"

namespace lidarsim::nn {

LossParts masked_mse(const Tensor& pred, const Tensor& target, const Tensor& mask, Tensor* d_pred,
                     long denominator) {
  if (!(pred.shape() == target.shape()))
    throw Error("masked_mse: target: expected shape " + pred.shape().str() + ", got " + target.shape().str());
  if (!(pred.shape() == mask.shape()))
    throw Error("masked_mse: mask: expected shape " + pred.shape().str() + ", got " + mask.shape().str());
  const std::size_t n = pred.numel();
  const float* p = pred.data();
  const float* t = target.data();
  const float* m = mask.data();
  // In double over fixed chunks added in order: the same sum for every thread count (serially,
  // batch 4 at 64 x 1024 left the other thread idle for 1 ms per step).
  constexpr std::size_t kChunk = 1 << 14;
  const std::size_t chunks = (n + kChunk - 1) / kChunk;
  std::vector<double> sums(chunks, 0.0);
  std::vector<long> counts(chunks, 0);
  std::atomic<bool> bad{false};
  detail::parallel_for(static_cast<long>(chunks), n > (1u << 15), [&](long c) {
    double s = 0;
    long v = 0;
    for (std::size_t i = c * kChunk; i < std::min(n, (c + 1) * kChunk); ++i) {
      if (!std::isfinite(m[i]) || (m[i] != 0.f && (!std::isfinite(t[i]) || !std::isfinite(p[i])))) {
        bad = true;
        return;
      }
      if (m[i] == 0.f) continue;
      const double d = static_cast<double>(p[i]) - t[i];
      s += m[i] * d * d;
      ++v;
    }
    sums[c] = s;
    counts[c] = v;
  });
  if (bad)  // name the first bad cell, in flat order
    for (std::size_t i = 0; i < n; ++i) {
      if (!std::isfinite(m[i])) throw Error("masked_mse: mask: non-finite value at flat index " + std::to_string(i));
      if (m[i] == 0.f) continue;
      if (!std::isfinite(t[i]))
        throw Error("masked_mse: target: non-finite value at flat index " + std::to_string(i));
      if (!std::isfinite(p[i]))
        throw Error("masked_mse: pred: non-finite value at flat index " + std::to_string(i) +
                    " (training diverged?)");
    }
  double sum = 0;
  long valid = 0;
  for (std::size_t c = 0; c < chunks; ++c) sum += sums[c], valid += counts[c];
  const double denom = denominator > 0 ? static_cast<double>(denominator) : valid > 0 ? static_cast<double>(valid) : 1.0;
  if (d_pred) {
    if (!(d_pred->shape() == pred.shape())) d_pred->resize(pred.shape());
    float* g = d_pred->data();
    const float scale = static_cast<float>(2.0 / denom);
    detail::parallel_ranges(static_cast<long>(n), n > (1u << 15), [&](long b, long e) {
      for (long i = b; i < e; ++i) g[i] = m[i] == 0.f ? 0.f : scale * m[i] * (p[i] - t[i]);
    });
  }
  LossParts parts;
  parts.data = sum / denom;
  parts.valid = valid;
  return parts;
}

double l2_penalty(ParamArena& params, float lambda, bool grads) {
  if (!std::isfinite(lambda) || lambda < 0)
    throw Error("l2_penalty: lambda: expected a finite value >= 0, got " + std::to_string(lambda));
  if (lambda == 0.f) return 0.0;
  // Per-parameter sums in double, added in registration order: independent of thread count.
  const auto& infos = params.infos();
  std::vector<double> partial(infos.size(), 0.0);
  // Parameters differ in size by 1000x: threads take the next one from a shared counter.
  std::atomic<long> next{0};
  detail::parallel(params.size() > (1u << 15), [&](int, int) {
    for (long i; (i = next.fetch_add(1, std::memory_order_relaxed)) < static_cast<long>(infos.size());) {
      if (!infos[i].decays) continue;
      const float* w = params.values() + infos[i].offset;
      float* g = params.grads() + infos[i].offset;
      const std::size_t n = infos[i].shape.numel();
      const float c = infos[i].decay_center;
      double s = 0;
      for (std::size_t j = 0; j < n; ++j) s += static_cast<double>(w[j] - c) * (w[j] - c);
      partial[i] = s;
      if (grads) {
        const float two_lambda = 2.f * lambda;
        for (std::size_t j = 0; j < n; ++j) g[j] += two_lambda * (w[j] - c);
      }
    }
  });
  double total = 0;
  for (double s : partial) total += s;
  return lambda * total;
}

}  // namespace lidarsim::nn
