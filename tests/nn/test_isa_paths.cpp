// Every kernel path this CPU has, and the forced AVX2 path (nn/cpu_features.h), against the
// double-precision reference: forward passes, finite-difference gradients, and the same bits on
// repeated runs within a path. Levels the CPU lacks skip with a message; CI's sanitized pass runs
// the whole suite again at LIDARSIM_ISA=avx2 (scripts/test.sh).
#include <gtest/gtest.h>
#include <omp.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <optional>
#include <string>
#include <vector>

#include "common/error.h"
#include "conv_path.h"
#include "nn/conv3x3.h"
#include "nn/conv3x3_amx.h"
#include "nn/conv3x3_bf16.h"
#include "nn/conv_transpose2x2.h"
#include "nn/cpu_features.h"
#include "nn/layers.h"
#include "nn/precision.h"
#include "nn/unet.h"
#include "nn/winograd.h"
#include "reference.h"

namespace lidarsim::nn {
namespace {

using namespace reference;

std::vector<double> as_double_vector(const std::vector<float>& v) { return {v.begin(), v.end()}; }
std::vector<double> as_double_vector(const Tensor& t) { return {t.begin(), t.end()}; }

class IsaPath : public ::testing::TestWithParam<Isa> {
 protected:
  void SetUp() override {
    if (static_cast<int>(GetParam()) > static_cast<int>(cpu_isa()))
      GTEST_SKIP() << "this CPU runs at most " << to_string(cpu_isa()) << ": no " << to_string(GetParam())
                   << " path to test here";
    scope_.emplace(GetParam());
  }
  void TearDown() override { scope_.reset(); }
  std::optional<testhook::ScopedIsa> scope_;
};

// The kernels the dispatch point offers at each level, and nothing wider.
TEST_P(IsaPath, OffersExactlyTheKernelsOfItsLevel) {
  const bool wide = GetParam() != Isa::avx2;
  EXPECT_EQ(active_isa(), GetParam());
  EXPECT_EQ(detail::conv3x3_available(), wide);
  EXPECT_EQ(detail::winograd_available(), wide || LIDARSIM_AVX2_KERNELS);  // at avx2: the AVX2 port
  EXPECT_EQ(detail::conv_transpose2x2_available(), wide);
  const bool bf16 = static_cast<int>(GetParam()) >= static_cast<int>(Isa::avx512_bf16);
  EXPECT_EQ(detail::conv3x3_bf16_available(), bf16);
  EXPECT_EQ(bf16_supported(), bf16);
  EXPECT_EQ(detail::conv3x3_amx_available(), GetParam() == Isa::amx_bf16);
  if (GetParam() != Isa::amx_bf16) {
    EXPECT_FALSE(detail::conv3x3_takes_amx(1, 64, 64, 64, 256));
  }
}

struct Errors {
  double forward, d_in, d_weight, d_bias;
};

// conv2d 3x3 (pad 1, ReLU) against the reference and central differences: direct (AVX-512) or
// GEMM (AVX2) with few channels, Winograd where both sides have 16 (at every level).
Errors check_conv3x3(int ci, int co, int h, int w) {
  const int k = 3, pad = 1;
  const Tensor x = random_tensor(Shape{1, ci, h, w}, 1);
  const std::vector<float> wt = random_vector(std::size_t(co) * ci * 9, 2, 0.5f), b = random_vector(co, 3, 0.3f);
  Tensor y, d_in;
  conv2d_forward(y, x, wt.data(), b.data(), co, k, pad, true);
  const Tensor r = random_tensor(y.shape(), 4);
  std::vector<float> dw(wt.size(), 0.f), db(b.size(), 0.f);
  conv2d_backward(&d_in, dw.data(), db.data(), r, y, x, wt.data(), k, pad, true);
  DT xd = from(x);
  std::vector<double> wd = as_double_vector(wt), bd = as_double_vector(b);
  const std::vector<double> rd = as_double_vector(r);
  auto f = [&] { return dot(conv2d(xd, wd, bd, co, k, pad, true), rd); };
  Errors e{max_rel_error(y.data(), conv2d(xd, wd, bd, co, k, pad, true).v), 0, 0, 0};
  e.d_in = max_rel_error(d_in.data(), numeric_gradient(xd.v, f));
  e.d_weight = max_rel_error(dw.data(), numeric_gradient(wd, f));
  e.d_bias = max_rel_error(db.data(), numeric_gradient(bd, f));
  std::printf("[ measured ] %s conv3x3 %d -> %d: forward %.1e, d_in %.1e, d_weight %.1e, d_bias %.1e\n",
              to_string(active_isa()), ci, co, e.forward, e.d_in, e.d_weight, e.d_bias);
  return e;
}

TEST_P(IsaPath, Conv3x3GradientsMatchFiniteDifferences) {
  struct Case {
    int ci, co, h, w;
  };
  for (const Case& c : {Case{3, 5, 7, 19}, Case{16, 16, 5, 9}}) {
    SCOPED_TRACE(std::to_string(c.ci) + " -> " + std::to_string(c.co));
    const Errors e = check_conv3x3(c.ci, c.co, c.h, c.w);
    EXPECT_LT(e.forward, 2e-5);
    EXPECT_LT(e.d_in, 1e-4);
    EXPECT_LT(e.d_weight, 1e-4);
    EXPECT_LT(e.d_bias, 1e-4);
  }
}

// Every level has a Winograd kernel (AVX2: its port, nn/winograd_avx2.h), the rule gives it the
// layers with 16 channels on both sides, and its results are its own (not the direct kernel's or
// the GEMM's bits) and right: forward and all gradients against the reference, partial tiles and
// 8-channel groups included.
TEST_P(IsaPath, WinogradRunsAtEveryLevelAndMatchesTheReference) {
  ASSERT_TRUE(detail::winograd_available());
  if (GetParam() == Isa::avx2) {  // the rule against im2col + GEMM: by pixels in the batch
    EXPECT_TRUE(detail::conv3x3_avx2_takes_winograd(16, 16, 1, 64, 1024, detail::Conv3x3Path::automatic));
    EXPECT_FALSE(detail::conv3x3_avx2_takes_winograd(256, 256, 1, 4, 64, detail::Conv3x3Path::automatic));
    EXPECT_TRUE(detail::conv3x3_avx2_takes_winograd(256, 256, 4, 4, 64, detail::Conv3x3Path::automatic));
  } else {  // against the direct kernel: by channels
    EXPECT_TRUE(detail::conv3x3_takes_winograd(16, 16, detail::Conv3x3Path::automatic));
    EXPECT_FALSE(detail::conv3x3_takes_winograd(4, 16, detail::Conv3x3Path::automatic));
  }
  const Tensor x = random_tensor(Shape{2, 20, 9, 37}, 41);
  const std::vector<float> wt = random_vector(std::size_t(24) * 20 * 9, 42, 0.2f);
  Tensor y_direct, y_wino;
  {
    conv_paths::Conv3x3PathGuard direct(detail::Conv3x3Path::direct);
    conv2d_forward(y_direct, x, wt.data(), nullptr, 24, 3, 1, false);
  }
  conv_paths::Conv3x3PathGuard winograd(detail::Conv3x3Path::winograd);
  conv2d_forward(y_wino, x, wt.data(), nullptr, 24, 3, 1, false);
  EXPECT_NE(std::memcmp(y_direct.data(), y_wino.data(), y_wino.numel() * sizeof(float)), 0)
      << "the Winograd path gave the direct path's bits: it did not run";
  const Errors e = check_conv3x3(17, 9, 5, 11);  // few values: the finite differences cost two passes each
  EXPECT_LT(e.forward, 2e-5);
  EXPECT_LT(e.d_in, 1e-4);
  EXPECT_LT(e.d_weight, 1e-4);
  EXPECT_LT(e.d_bias, 1e-4);
}

TEST_P(IsaPath, TransposedConvAndMaxPoolMatchTheReference) {
  const Tensor x = random_tensor(Shape{2, 5, 3, 37}, 31);
  const std::vector<float> wt = random_vector(5 * 3 * 4, 32, 0.5f), b = random_vector(3, 33, 0.3f);
  Tensor y;
  conv_transpose2x2_forward(y, x, wt.data(), b.data(), 3, 7, 75);
  EXPECT_LT(max_rel_error(y.data(), conv_transpose2x2(from(x), as_double_vector(wt), as_double_vector(b), 3, 7, 75).v), 1e-5);

  // 70 columns: 35 windows per row, two full 16-window vectors and a scalar tail. Ties (argmax:
  // the first of equal values in row order): between the rows of plane 0's first windows, and all
  // four values of plane 1's second row of windows.
  Tensor p = random_tensor(Shape{1, 2, 6, 70}, 34);
  for (int xx = 0; xx < 70; ++xx) {
    p.at(0, 0, 1, xx) = p.at(0, 0, 0, xx ^ 1);
    p.at(0, 1, 2, xx) = p.at(0, 1, 3, xx) = 0.5f;
  }
  Tensor q;
  std::vector<std::int32_t> am;
  max_pool2x2_forward(q, am, p);
  const DT ref = max_pool2x2(from(p));
  for (std::size_t i = 0; i < q.numel(); ++i) {
    ASSERT_EQ(q.data()[i], static_cast<float>(ref.v[i])) << "window " << i;
    const int plane = static_cast<int>(i / q.shape().plane()), wi = static_cast<int>(i % q.shape().plane());
    const int oy = wi / 35, ox = wi % 35;
    int best = -1;
    float v = 0;
    for (int dy = 0; dy < 2; ++dy)
      for (int dx = 0; dx < 2; ++dx) {
        const float c = p.at(0, plane, 2 * oy + dy, 2 * ox + dx);
        if (best < 0 || c > v) v = c, best = (2 * oy + dy) * 70 + 2 * ox + dx;
      }
    ASSERT_EQ(am[i], best) << "window " << i;
  }
}

// Within a path, a UNet step gives the same gradient bits on every run, at 1 and 2 threads.
TEST_P(IsaPath, UNetGradientsAreTheSameBitsRunToRunAtEachThreadCount) {
  UNet model(UNetConfig{3, 1, 8, 2});
  model.init(11);
  const Tensor x = random_tensor(Shape{2, 3, 32, 80}, 12), dy = random_tensor(Shape{2, 1, 32, 80}, 13);
  const int saved = omp_get_max_threads();
  for (int threads : {1, 2}) {
    omp_set_num_threads(threads);
    std::vector<float> first;
    for (int run = 0; run < 2; ++run) {
      Tensor y;
      model.params().zero_grads();
      model.forward(x, y);
      model.backward(dy);
      const float* g = model.params().grads();
      if (run == 0)
        first.assign(g, g + model.params().size());
      else
        EXPECT_EQ(std::memcmp(first.data(), g, first.size() * sizeof(float)), 0) << threads << " threads";
    }
  }
  omp_set_num_threads(saved);
}

INSTANTIATE_TEST_SUITE_P(EveryLevel, IsaPath,
                         ::testing::Values(Isa::avx2, Isa::avx512, Isa::avx512_bf16, Isa::amx_bf16),
                         [](const ::testing::TestParamInfo<Isa>& i) { return std::string(to_string(i.param)); });

TEST(CpuFeatures, ParsesTheLevelNamesAndRejectsTheRest) {
  for (int i = 0; i < kIsaCount; ++i) EXPECT_EQ(parse_isa(kIsaNames[i], "f"), static_cast<Isa>(i));
  try {
    parse_isa("avx9", "environment: LIDARSIM_ISA");
    FAIL() << "accepted avx9";
  } catch (const Error& e) {
    EXPECT_STREQ(e.what(),
                 "environment: LIDARSIM_ISA: expected auto, avx2, avx512, avx512_bf16 or amx_bf16, got \"avx9\"");
  }
}

TEST(CpuFeatures, ALevelAboveTheCpuIsAnErrorNotASilentFallback) {
  if (cpu_isa() == Isa::amx_bf16) GTEST_SKIP() << "this CPU has every level";
  const Isa above = static_cast<Isa>(static_cast<int>(cpu_isa()) + 1);
  EXPECT_THROW(testhook::set_isa(above), Error);
  EXPECT_NE(active_isa(), above);
}

// LIDARSIM_ISA is read once, on first use: a bad value is one clear error (the death test runs
// in a fresh process, where nothing has read it yet).
TEST(CpuFeaturesDeathTest, BadLidarsimIsaIsOneClearError) {
  GTEST_FLAG_SET(death_test_style, "threadsafe");
  EXPECT_EXIT(
      {
        setenv("LIDARSIM_ISA", "sse2", 1);
        try {
          active_isa();
        } catch (const Error& e) {
          std::fprintf(stderr, "error: %s\n", e.what());
          std::exit(2);
        }
        std::exit(0);
      },
      ::testing::ExitedWithCode(2),
      "error: environment: LIDARSIM_ISA: expected auto, avx2, avx512, avx512_bf16 or amx_bf16");
}

}  // namespace
}  // namespace lidarsim::nn
