// The extra heads' losses (nn/loss.h): binary cross-entropy on logits and the Gaussian / Laplace
// negative log-likelihoods, masked means with masked_mse's conventions.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <string>
#include <vector>

#include "common/error.h"
#include "nn/loss.h"
#include "nn/parallel.h"

namespace lidarsim::nn {
namespace {

struct Input {
  const char* name;
  const Tensor* t;
};

void check_shapes(const char* op, const Shape& want, std::initializer_list<Input> inputs) {
  for (const Input& in : inputs)
    if (!(in.t->shape() == want))
      throw Error(std::string(op) + ": " + in.name + ": expected shape " + want.str() + ", got " + in.t->shape().str());
}

// Sum of m[i] * cell(i) over masked-in cells, in double over fixed chunks added in order: the
// same sum for every thread count. Every input must be finite in masked-in cells and `in_range`
// hold there; otherwise the first bad cell in flat order is named.
template <class Cell, class InRange>
std::pair<double, long> masked_sum(const char* op, const Tensor& mask, std::initializer_list<Input> inputs, Cell cell,
                                   InRange in_range, const char* range_field, const char* range_text) {
  const std::size_t n = mask.numel();
  const float* m = mask.data();
  const std::vector<Input> ins(inputs);
  const auto good = [&](std::size_t i) {
    if (!std::isfinite(m[i])) return false;
    if (m[i] == 0.f) return true;
    for (const Input& in : ins)
      if (!std::isfinite(in.t->data()[i])) return false;
    return in_range(i);
  };
  constexpr std::size_t kChunk = 1 << 14;
  const std::size_t chunks = (n + kChunk - 1) / kChunk;
  std::vector<double> sums(chunks, 0.0);
  std::vector<long> counts(chunks, 0);
  std::atomic<bool> bad{false};
  detail::parallel_for(static_cast<long>(chunks), n > (1u << 15), [&](long c) {
    double s = 0;
    long v = 0;
    for (std::size_t i = c * kChunk; i < std::min(n, (c + 1) * kChunk); ++i) {
      if (!good(i)) {
        bad = true;
        return;
      }
      if (m[i] == 0.f) continue;
      s += m[i] * cell(i);
      ++v;
    }
    sums[c] = s;
    counts[c] = v;
  });
  if (bad)
    for (std::size_t i = 0; i < n; ++i) {
      const std::string at = " at flat index " + std::to_string(i);
      if (!std::isfinite(m[i])) throw Error(std::string(op) + ": mask: non-finite value" + at);
      if (m[i] == 0.f) continue;
      for (const Input& in : ins)
        if (!std::isfinite(in.t->data()[i])) throw Error(std::string(op) + ": " + in.name + ": non-finite value" + at);
      if (!in_range(i)) throw Error(std::string(op) + ": " + range_field + ": " + range_text + at);
    }
  double sum = 0;
  long valid = 0;
  for (std::size_t c = 0; c < chunks; ++c) sum += sums[c], valid += counts[c];
  return {sum, valid};
}

double denominator_of(long denominator, long valid) {
  return denominator > 0 ? static_cast<double>(denominator) : valid > 0 ? static_cast<double>(valid) : 1.0;
}

// g[i] = m[i] * grad(i) / denom in masked-in cells, 0 elsewhere.
template <class Grad>
void masked_grad(Tensor* d, const Tensor& mask, double denom, Grad grad) {
  if (!d) return;
  if (!(d->shape() == mask.shape())) d->resize(mask.shape());
  float* g = d->data();
  const float* m = mask.data();
  const std::size_t n = mask.numel();
  detail::parallel_ranges(static_cast<long>(n), n > (1u << 15), [&](long b, long e) {
    for (long i = b; i < e; ++i) g[i] = m[i] == 0.f ? 0.f : static_cast<float>(m[i] * grad(i) / denom);
  });
}

}  // namespace

LossParts masked_bce_logits(const Tensor& logit, const Tensor& target, const Tensor& mask, Tensor* d_logit,
                            long denominator) {
  const char* op = "masked_bce_logits";
  check_shapes(op, logit.shape(), {{"target", &target}, {"mask", &mask}});
  const float* z = logit.data();
  const float* y = target.data();
  const auto cell = [&](std::size_t i) {
    const double zi = z[i];
    return std::max(zi, 0.0) - zi * y[i] + std::log1p(std::exp(-std::abs(zi)));
  };
  const auto in_range = [&](std::size_t i) { return y[i] >= 0.f && y[i] <= 1.f; };
  const auto [sum, valid] =
      masked_sum(op, mask, {{"logit", &logit}, {"target", &target}}, cell, in_range, "target", "expected 0..1");
  const double denom = denominator_of(denominator, valid);
  masked_grad(d_logit, mask, denom, [&](long i) {
    const double zi = z[i];  // sigmoid without overflow: exp of a non-positive number only
    const double e = std::exp(-std::abs(zi));
    const double p = zi >= 0 ? 1.0 / (1.0 + e) : e / (1.0 + e);
    return p - y[i];
  });
  LossParts parts;
  parts.data = sum / denom;
  parts.valid = valid;
  return parts;
}

LossParts masked_nll(Spread family, const Tensor& mean, const Tensor& log_scale, const Tensor& target,
                     const Tensor& mask, Tensor* d_mean, Tensor* d_log_scale, long denominator, LogScaleClamp clamp) {
  const char* op = family == Spread::gaussian ? "masked_nll (gaussian)" : "masked_nll (laplace)";
  if (!(clamp.min <= clamp.max) || !std::isfinite(clamp.min) || !std::isfinite(clamp.max))
    throw Error(std::string(op) + ": clamp: expected finite min <= max, got " + std::to_string(clamp.min) + ", " +
                std::to_string(clamp.max));
  check_shapes(op, mean.shape(), {{"log_scale", &log_scale}, {"target", &target}, {"mask", &mask}});
  const float* mu = mean.data();
  const float* s = log_scale.data();
  const float* y = target.data();
  const double lo = clamp.min, hi = clamp.max;
  const auto s_of = [&](std::size_t i) { return std::clamp(static_cast<double>(s[i]), lo, hi); };
  const bool gauss = family == Spread::gaussian;
  const double constant = gauss ? 0.5 * std::log(2 * M_PI) : std::log(2.0);
  const auto cell = [&](std::size_t i) {
    const double si = s_of(i), r = static_cast<double>(y[i]) - mu[i];
    return gauss ? si + 0.5 * r * r * std::exp(-2 * si) + constant : si + std::abs(r) * std::exp(-si) + constant;
  };
  const auto [sum, valid] = masked_sum(op, mask, {{"mean", &mean}, {"log_scale", &log_scale}, {"target", &target}},
                                       cell, [](std::size_t) { return true; }, "", "");
  const double denom = denominator_of(denominator, valid);
  masked_grad(d_mean, mask, denom, [&](long i) {
    const double si = s_of(i), r = static_cast<double>(mu[i]) - y[i];
    return gauss ? r * std::exp(-2 * si) : (r > 0 ? 1.0 : r < 0 ? -1.0 : 0.0) * std::exp(-si);
  });
  masked_grad(d_log_scale, mask, denom, [&](long i) {
    if (s[i] < lo || s[i] > hi) return 0.0;  // clamped: as torch.clamp, no gradient
    const double si = s[i], r = static_cast<double>(y[i]) - mu[i];
    return gauss ? 1.0 - r * r * std::exp(-2 * si) : 1.0 - std::abs(r) * std::exp(-si);
  });
  LossParts parts;
  parts.data = sum / denom;
  parts.valid = valid;
  return parts;
}

}  // namespace lidarsim::nn
