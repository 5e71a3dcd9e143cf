// Winograd F(4x4, 3x3) against the direct 3x3 kernel on the same inputs: forward (bias, ReLU),
// input and weight gradients (masked by the ReLU), plain and over a channel concat, on sizes that are not
// multiples of the 4 x 4 tile or of the 16-tile vectors. Inputs are ReLU-like activations (half
// zeros) and He-scaled weights, as in the UNet. Error = max |winograd - direct| / max |direct|
// over the whole output; F(4x4, 3x3) in float loses a few bits to its transforms (the 1/24 and
// 8x factors): measured 4.7e-6 (forward) and 3.2e-6 (input gradient) here, so the tolerance is
// 2e-5 (one weight off by 1 % already gives ~1e-3).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include <omp.h>

#include "conv_path.h"
#include "nn/cpu_features.h"
#include "nn/layers.h"
#include "nn/winograd.h"

namespace lidarsim::nn {
namespace {

using detail::Conv3x3Path;
using conv_paths::Conv3x3PathGuard;

constexpr double kWinogradTol = 2e-5;

Tensor winograd_activations(Shape s, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> normal;
  Tensor t(s);
  for (float& v : t) v = std::max(normal(rng), 0.f);
  return t;
}

std::vector<float> winograd_he_weights(int co, int ci, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> normal(0.f, std::sqrt(2.f / (9.f * ci)));
  std::vector<float> w(static_cast<std::size_t>(co) * ci * 9);
  for (float& v : w) v = normal(rng);
  return w;
}

struct Diff {
  double max_abs = 0, scale = 0;
  double rel() const { return max_abs / std::max(scale, 1e-30); }
};

Diff compare(const std::vector<float>& a, const std::vector<float>& ref) {
  Diff d;
  EXPECT_EQ(a.size(), ref.size());
  for (std::size_t i = 0; i < ref.size(); ++i) {
    d.max_abs = std::max(d.max_abs, static_cast<double>(std::abs(a[i] - ref[i])));
    d.scale = std::max(d.scale, static_cast<double>(std::abs(ref[i])));
  }
  return d;
}

Diff compare(const Tensor& a, const Tensor& ref) {
  Diff d;
  EXPECT_EQ(a.shape(), ref.shape());
  for (std::size_t i = 0; i < ref.numel(); ++i) {
    d.max_abs = std::max(d.max_abs, static_cast<double>(std::abs(a.data()[i] - ref.data()[i])));
    d.scale = std::max(d.scale, static_cast<double>(std::abs(ref.data()[i])));
  }
  return d;
}

// The levels with a Winograd kernel on this CPU: the AVX2 port everywhere, the AVX-512 kernels
// where the CPU has them; each test runs on all of them (testhook::ScopedIsa).
std::vector<Isa> winograd_levels() {
  std::vector<Isa> levels;
  if (LIDARSIM_AVX2_KERNELS) levels.push_back(Isa::avx2);
  if (isa_at_least(Isa::avx512)) levels.push_back(Isa::avx512);
  return levels;
}

struct WinogradCase {
  int n, ci, co, h, w;
};

// Odd sizes: partial tiles in both directions, rows shorter and longer than one 16-tile vector,
// a 1 x 1 map, and more channels than one 8-channel register block.
const WinogradCase kWinogradCases[] = {{2, 5, 11, 7, 9},   {1, 16, 24, 13, 37}, {1, 3, 8, 1, 1},   {2, 32, 16, 5, 70},
                       {1, 8, 8, 4, 64},   {1, 20, 9, 9, 100},  {3, 7, 5, 6, 3},   {1, 12, 40, 2, 250}};

struct Outputs {
  Tensor y, d_in;
  std::vector<float> d_w;
};

Outputs run_plain(const WinogradCase& c, bool relu, Conv3x3Path path) {
  Conv3x3PathGuard guard(path);
  EXPECT_EQ(detail::conv3x3_takes_winograd(c.ci, c.co), path == Conv3x3Path::winograd);
  const Tensor x = winograd_activations(Shape{c.n, c.ci, c.h, c.w}, 1);
  const std::vector<float> w = winograd_he_weights(c.co, c.ci, 2);
  std::vector<float> b(static_cast<std::size_t>(c.co));
  for (int o = 0; o < c.co; ++o) b[o] = 0.05f * (o % 5) - 0.1f;
  Outputs r;
  conv2d_forward(r.y, x, w.data(), b.data(), c.co, 3, 1, relu);
  const Tensor g = winograd_activations(r.y.shape(), 3);
  r.d_w.assign(w.size(), 0.f);
  conv2d_backward(&r.d_in, r.d_w.data(), nullptr, g, r.y, x, w.data(), 3, 1, relu);
  return r;
}

TEST(Winograd, ForwardInputAndWeightGradientsMatchDirectOnOddSizes) {
  if (!detail::winograd_available()) GTEST_SKIP() << "built without AVX2 kernels (LIDARSIM_ARCH below x86-64-v3): no Winograd path";
  for (const Isa level : winograd_levels()) {
  testhook::ScopedIsa isa(level);
  double worst_fwd = 0, worst_din = 0, worst_dw = 0;
  for (const WinogradCase& c : kWinogradCases)
    for (bool relu : {false, true}) {
      SCOPED_TRACE(std::string(to_string(level)) + " n " + std::to_string(c.n) + " ci " + std::to_string(c.ci) + " co " + std::to_string(c.co) + " " +
                   std::to_string(c.h) + "x" + std::to_string(c.w) + " relu " + std::to_string(relu));
      const Outputs direct = run_plain(c, relu, Conv3x3Path::direct);
      const Outputs wino = run_plain(c, relu, Conv3x3Path::winograd);
      const Diff f = compare(wino.y, direct.y), d = compare(wino.d_in, direct.d_in), dw = compare(wino.d_w, direct.d_w);
      EXPECT_LT(f.rel(), kWinogradTol) << "forward: max abs " << f.max_abs << " of " << f.scale;
      EXPECT_LT(d.rel(), kWinogradTol) << "input gradient: max abs " << d.max_abs << " of " << d.scale;
      EXPECT_LT(dw.rel(), kWinogradTol) << "weight gradient: max abs " << dw.max_abs << " of " << dw.scale;
      worst_fwd = std::max(worst_fwd, f.rel());
      worst_din = std::max(worst_din, d.rel());
      worst_dw = std::max(worst_dw, dw.rel());
    }
  std::printf(
      "[ measured ] %s: winograd vs direct, max |diff| / max |direct|: forward %.2e, input gradient %.2e, weight "
      "gradient %.2e\n",
      to_string(level), worst_fwd, worst_din, worst_dw);
  }
}

Outputs run_cat(const WinogradCase& c, int ca, Conv3x3Path path, Tensor* d_b) {
  Conv3x3PathGuard guard(path);
  const Tensor a = winograd_activations(Shape{c.n, ca, c.h, c.w}, 4), b = winograd_activations(Shape{c.n, c.ci - ca, c.h, c.w}, 5);
  const std::vector<float> w = winograd_he_weights(c.co, c.ci, 6);
  const std::vector<float> bias(static_cast<std::size_t>(c.co), 0.02f);
  Outputs r;
  conv2d_cat_forward(r.y, a, b, w.data(), bias.data(), c.co, true);
  const Tensor g = winograd_activations(r.y.shape(), 7);
  r.d_w.assign(w.size(), 0.f);
  conv2d_cat_backward(r.d_in, *d_b, r.d_w.data(), nullptr, g, r.y, a, b, w.data(), true);
  return r;
}

// The weight gradient's 16-channel groups straddle the two buffers when ca is not a multiple of 16.
TEST(Winograd, ConcatForwardSplitInputGradientAndWeightGradientMatchDirect) {
  if (!detail::winograd_available()) GTEST_SKIP() << "built without AVX2 kernels (LIDARSIM_ARCH below x86-64-v3): no Winograd path";
  for (const Isa level : winograd_levels())
  for (const WinogradCase& c : {WinogradCase{2, 10, 6, 7, 9}, WinogradCase{1, 32, 16, 9, 66}, WinogradCase{2, 40, 24, 6, 70}}) {
    testhook::ScopedIsa isa(level);
    SCOPED_TRACE(to_string(level));
    Tensor db_direct, db_wino;
    const Outputs direct = run_cat(c, c.ci / 2 - 1, Conv3x3Path::direct, &db_direct);
    const Outputs wino = run_cat(c, c.ci / 2 - 1, Conv3x3Path::winograd, &db_wino);
    EXPECT_LT(compare(wino.y, direct.y).rel(), kWinogradTol);
    EXPECT_LT(compare(wino.d_in, direct.d_in).rel(), kWinogradTol);
    EXPECT_LT(compare(db_wino, db_direct).rel(), kWinogradTol);
    EXPECT_LT(compare(wino.d_w, direct.d_w).rel(), kWinogradTol);
  }
}

// The weight gradient sums its tiles in slots fixed by the shapes, so 1, 2 and 3 threads give the
// same bits: on a map with more chunks than slots (and a partial last chunk per row), and on a
// deep layer with few tiles, where the tasks also split the output channels.
TEST(Winograd, WeightGradientIsTheSameBitsOnAnyThreadCount) {
  if (!detail::winograd_available()) GTEST_SKIP() << "built without AVX2 kernels (LIDARSIM_ARCH below x86-64-v3): no Winograd path";
  const int saved = omp_get_max_threads();
  for (const Isa level : winograd_levels())
  for (const WinogradCase& c : {WinogradCase{2, 16, 16, 64, 700}, WinogradCase{2, 64, 72, 8, 20}}) {
    testhook::ScopedIsa isa(level);
    SCOPED_TRACE(std::string(to_string(level)) + " ci " + std::to_string(c.ci) + " co " + std::to_string(c.co));
    const Tensor x = winograd_activations(Shape{c.n, c.ci, c.h, c.w}, 21);
    const Tensor g = winograd_activations(Shape{c.n, c.co, c.h, c.w}, 22);
    std::vector<float> first;
    for (int threads : {1, 2, 3}) {
      omp_set_num_threads(threads);
      std::vector<float> dw(static_cast<std::size_t>(c.co) * c.ci * 9, 0.f);
      detail::winograd_weight_grad(dw.data(), detail::PlaneSet{x.data(), c.ci}, g.data(), nullptr, c.n, c.h, c.w, c.co);
      if (first.empty()) {
        first = dw;
        // and it is the gradient: against the direct kernel
        Conv3x3PathGuard guard(Conv3x3Path::direct);
        std::vector<float> ref(dw.size(), 0.f);
        const std::vector<float> w = winograd_he_weights(c.co, c.ci, 23);
        Tensor y;
        conv2d_forward(y, x, w.data(), nullptr, c.co, 3, 1, false);
        conv2d_backward(nullptr, ref.data(), nullptr, g, y, x, w.data(), 3, 1, false);
        EXPECT_LT(compare(dw, ref).rel(), kWinogradTol);
      } else {
        EXPECT_EQ(std::memcmp(first.data(), dw.data(), dw.size() * sizeof(float)), 0) << threads << " threads";
      }
    }
  }
  omp_set_num_threads(saved);
}

// The transformed weights against G k G^T evaluated plainly in double (the matrix as fractions,
// every product summed) and rounded to float: the factored transform must stay within 1 ulp,
// for plain and flipped weights and a last block of output channels that is partly empty.
TEST(Winograd, TransformedWeightsMatchThePlainDoubleTransform) {
  if (!detail::winograd_available()) GTEST_SKIP() << "built without AVX2 kernels (LIDARSIM_ARCH below x86-64-v3): no Winograd path";
  static constexpr double G[6][3] = {{1.0 / 4, 0, 0},         {-1.0 / 6, -1.0 / 6, -1.0 / 6},
                                     {-1.0 / 6, 1.0 / 6, -1.0 / 6}, {1.0 / 24, 1.0 / 12, 1.0 / 6},
                                     {1.0 / 24, -1.0 / 12, 1.0 / 6}, {0, 0, 1}};
  double worst_ulps = 0;
  for (const Isa level : winograd_levels())
  for (const bool flip : {false, true}) {
    testhook::ScopedIsa isa(level);
    const int co = 13, ci = 5;  // of the conv that runs: flipped, the weight is [ci][co][3][3]
    const std::vector<float> w = winograd_he_weights(flip ? ci : co, flip ? co : ci, 9);
    const int blocks = (co + 7) / 8;
    const std::size_t per_e = detail::winograd_u_stride(co, ci);
    ASSERT_GE(per_e, static_cast<std::size_t>(blocks) * ci * 8);
    std::vector<float> storage(36 * per_e + 16, -1.f);  // U is stored with aligned 32-byte stores
    float* u = storage.data() + (16 - reinterpret_cast<std::uintptr_t>(storage.data()) / 4 % 16) % 16;
    detail::winograd_transform_weights(u, w.data(), co, ci, flip);
    for (int o = 0; o < blocks * 8; ++o)
      for (int c = 0; c < ci; ++c) {
        double k[3][3] = {};
        for (int t = 0; t < 9 && o < co; ++t)
          k[t / 3][t % 3] = flip ? w[(static_cast<std::size_t>(c) * co + o) * 9 + 8 - t]
                                 : w[(static_cast<std::size_t>(o) * ci + c) * 9 + t];
        for (int a = 0; a < 6; ++a)
          for (int b = 0; b < 6; ++b) {
            double ref = 0;
            for (int i = 0; i < 3; ++i)
              for (int j = 0; j < 3; ++j) ref += G[a][i] * k[i][j] * G[b][j];
            const float want = static_cast<float>(ref);
            const float got = u[(a * 6 + b) * per_e + (static_cast<std::size_t>(o / 8) * ci + c) * 8 + o % 8];
            const double ulp = std::max(std::abs(std::nextafter(want, 2 * want + 1.f) - want), 1e-30f);
            const double ulps = std::abs(static_cast<double>(got) - want) / ulp;
            EXPECT_LE(ulps, 1.0) << "flip " << flip << " o " << o << " c " << c << " element " << a << "," << b
                                 << ": " << got << " vs " << want;
            worst_ulps = std::max(worst_ulps, ulps);
          }
      }
  }
  std::printf("[ measured ] transformed weights vs the plain double transform: max %.1f ulp\n", worst_ulps);
}

TEST(Winograd, ComparisonCanFail) {
  // The same comparison with one weight changed by 1 % of its scale must exceed the tolerance.
  if (!detail::winograd_available()) GTEST_SKIP() << "built without AVX2 kernels (LIDARSIM_ARCH below x86-64-v3): no Winograd path";
  const WinogradCase c{1, 8, 8, 7, 9};
  const Tensor x = winograd_activations(Shape{c.n, c.ci, c.h, c.w}, 1);
  std::vector<float> w = winograd_he_weights(c.co, c.ci, 2);
  Tensor direct, wino;
  {
    Conv3x3PathGuard guard(Conv3x3Path::direct);
    conv2d_forward(direct, x, w.data(), nullptr, c.co, 3, 1, false);
  }
  w[40] += 0.01f * std::sqrt(2.f / (9.f * c.ci));
  {
    Conv3x3PathGuard guard(Conv3x3Path::winograd);
    conv2d_forward(wino, x, w.data(), nullptr, c.co, 3, 1, false);
  }
  EXPECT_GT(compare(wino, direct).rel(), 10 * kWinogradTol);
}

}  // namespace
}  // namespace lidarsim::nn
