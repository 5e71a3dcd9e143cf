#pragma once
// Inputs and the accuracy bound shared by the bf16 kernel tests (test_conv3x3_bf16.cpp,
// test_conv3x3_amx.cpp): ReLU-like activations, He weights, and per output element the
// magnitude sum |w| |x| over its 3x3 window and input channels, which the bf16 bound scales.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <random>
#include <vector>

#include "nn/precision.h"
#include "nn/tensor.h"

namespace lidarsim::nn::bf16_bound {

inline Tensor activations(Shape s, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> normal;
  Tensor t(s);
  for (float& v : t) v = std::max(normal(rng), 0.f);
  return t;
}

inline std::vector<float> he_weights(int co, int ci, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> normal(0.f, std::sqrt(2.f / (9.f * ci)));
  std::vector<float> w(static_cast<std::size_t>(co) * ci * 9);
  for (float& v : w) v = normal(rng);
  return w;
}

// sum over the 3x3 window and input channels of |w| |x| (zero padding), per output element.
inline std::vector<double> magnitude(const std::vector<const Tensor*>& ins, const std::vector<float>& w, int co) {
  const Shape s = ins[0]->shape();
  int ci = 0;
  for (const Tensor* t : ins) ci += t->shape().c;
  std::vector<double> m(static_cast<std::size_t>(s.n) * co * s.h * s.w, 0.0);
  for (int n = 0; n < s.n; ++n)
    for (int o = 0; o < co; ++o)
      for (int y = 0; y < s.h; ++y)
        for (int x = 0; x < s.w; ++x) {
          double acc = 0;
          int c = 0;
          for (const Tensor* t : ins)
            for (int tc = 0; tc < t->shape().c; ++tc, ++c)
              for (int ky = 0; ky < 3; ++ky)
                for (int kx = 0; kx < 3; ++kx) {
                  const int yy = y + ky - 1, xx = x + kx - 1;
                  if (yy < 0 || yy >= s.h || xx < 0 || xx >= s.w) continue;
                  acc += std::abs(w[(static_cast<std::size_t>(o) * ci + c) * 9 + ky * 3 + kx]) *
                         std::abs(t->channel(n, tc)[yy * s.w + xx]);
                }
          m[((static_cast<std::size_t>(n) * co + o) * s.h + y) * s.w + x] = acc;
        }
  return m;
}

// Sets the process's inference precision for a scope.
struct PrecisionGuard {
  explicit PrecisionGuard(InferencePrecision p) : old(inference_precision()) { set_inference_precision(p); }
  ~PrecisionGuard() { set_inference_precision(old); }
  InferencePrecision old;
};

}  // namespace lidarsim::nn::bf16_bound
