// The bf16 inference path (nn/conv3x3_bf16.h, nn/precision.h) against the fp32 path.
// Per output element the bound is 2^-7 x sum |w| |x| over its window (the dot product's
// magnitude): rounding each factor to bf16 (8-bit significand, unit roundoff 2^-8) moves a
// product by at most 2 x 2^-8 of itself, and the fp32 sums differ only in order (2^-20 more).
// Inputs are ReLU-like activations and He weights, as in the UNet; sizes are odd (partial
// 16-pixel vectors and 48-pixel strips, output channels not a multiple of the 8-channel block,
// an odd number of input channels so one pair has a zero partner, a concat split inside a pair).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include "bf16_bound.h"
#include "conv_path.h"
#include "nn/conv3x3_bf16.h"
#include "nn/cpu_features.h"
#include "nn/layers.h"
#include "nn/precision.h"
#include "nn/unet.h"

namespace lidarsim::nn {
namespace {

using conv_paths::Conv3x3PathGuard;
using detail::Conv3x3Path;
using namespace bf16_bound;

struct Case {
  int n, ca, cb, co, h, w;  // input = concat of ca and cb channels (cb 0: plain)
};

const Case kCases[] = {{1, 3, 0, 5, 7, 13},   {2, 17, 0, 9, 5, 50},  {1, 16, 0, 16, 9, 33}, {1, 1, 0, 8, 1, 1},
                       {3, 7, 0, 11, 6, 3},   {1, 12, 0, 40, 2, 100}, {2, 5, 6, 11, 6, 21}, {1, 16, 16, 16, 4, 64}};

// Runs one case in fp32 (direct path) and bf16; returns the worst |bf16 - fp32| / bound and
// the worst |bf16 - fp32| / max |fp32| through out parameters. swap01 feeds the bf16 kernel
// the first two input channels swapped (a pairing bug, for the test that the check can fail).
void run_case(const Case& c, bool relu, double* worst_bound, double* worst_rel, bool swap01 = false) {
  const Tensor a = activations(Shape{c.n, c.ca, c.h, c.w}, 1);
  const Tensor b = c.cb ? activations(Shape{c.n, c.cb, c.h, c.w}, 2) : Tensor();
  const std::vector<float> w = he_weights(c.co, c.ca + c.cb, 3);
  std::vector<float> bias(static_cast<std::size_t>(c.co));
  for (int o = 0; o < c.co; ++o) bias[o] = 0.05f * (o % 5) - 0.1f;
  Tensor y32, y16;
  {
    Conv3x3PathGuard guard(Conv3x3Path::direct);
    if (c.cb)
      conv2d_cat_forward(y32, a, b, w.data(), bias.data(), c.co, relu);
    else
      conv2d_forward(y32, a, w.data(), bias.data(), c.co, 3, 1, relu);
  }
  Tensor a16 = a;
  if (swap01)
    for (int n = 0; n < c.n; ++n) std::swap_ranges(a16.channel(n, 0), a16.channel(n, 0) + c.h * c.w, a16.channel(n, 1));
  {
    testhook::ScopedIsa isa(Isa::avx512_bf16);  // this kernel, not AMX (test_conv3x3_amx.cpp)
    detail::ConvSettings cs;
    cs.bf16 = true;  // the layer functions route to the bf16 kernel
    if (c.cb)
      conv2d_cat_forward(y16, a16, b, w.data(), bias.data(), c.co, relu, cs);
    else
      conv2d_forward(y16, a16, w.data(), bias.data(), c.co, 3, 1, relu, cs);
  }
  ASSERT_EQ(y16.shape(), y32.shape());
  std::vector<const Tensor*> ins{&a};
  if (c.cb) ins.push_back(&b);
  const std::vector<double> mag = magnitude(ins, w, c.co);
  double max_ref = 0, max_diff = 0;
  *worst_bound = 0;
  for (std::size_t i = 0; i < y32.numel(); ++i) {
    const int o = static_cast<int>(i / (static_cast<std::size_t>(c.h) * c.w)) % c.co;
    const double d = std::abs(static_cast<double>(y16.data()[i]) - y32.data()[i]);
    const double bound = 0x1p-7 * mag[i] + 0x1p-20 * (mag[i] + std::abs(bias[o])) + 1e-30;
    *worst_bound = std::max(*worst_bound, d / bound);
    max_diff = std::max(max_diff, d);
    max_ref = std::max(max_ref, static_cast<double>(std::abs(y32.data()[i])));
  }
  *worst_rel = max_diff / std::max(max_ref, 1e-30);
}

TEST(Conv3x3Bf16, MatchesFp32WithinBf16RoundingOnOddSizesAndConcats) {
  if (!detail::conv3x3_bf16_available()) GTEST_SKIP() << "this CPU has no AVX-512 BF16: no bf16 path to test";
  double worst_bound = 0, worst_rel = 0;
  for (const Case& c : kCases)
    for (bool relu : {false, true}) {
      SCOPED_TRACE("n " + std::to_string(c.n) + " ci " + std::to_string(c.ca) + "+" + std::to_string(c.cb) + " co " +
                   std::to_string(c.co) + " " + std::to_string(c.h) + "x" + std::to_string(c.w) + " relu " +
                   std::to_string(relu));
      double bound = 0, rel = 0;
      run_case(c, relu, &bound, &rel);
      EXPECT_LE(bound, 1.0) << "|bf16 - fp32| exceeds 2^-7 of the dot product's magnitude";
      // bf16 really ran: rounding 8-bit significands always shows somewhere (1x1 maps excepted:
      // with one input value per channel the product may be exact).
      if (c.h * c.w > 1) {
        EXPECT_GT(rel, 0.0) << "bit-identical to fp32: the bf16 kernel did not run";
      }
      worst_bound = std::max(worst_bound, bound);
      worst_rel = std::max(worst_rel, rel);
    }
  std::printf("[ measured ] bf16 vs fp32 conv: worst |diff| / bound %.3f, worst max |diff| / max |fp32| %.2e\n",
              worst_bound, worst_rel);
}

TEST(Conv3x3Bf16, ComparisonCanFail) {
  // Feeding the kernel the input channels of one pair swapped must break the bound.
  if (!detail::conv3x3_bf16_available()) GTEST_SKIP() << "this CPU has no AVX-512 BF16: no bf16 path to test";
  double bound = 0, rel = 0;
  run_case(Case{1, 4, 0, 8, 7, 20}, false, &bound, &rel, true);
  EXPECT_GT(bound, 1.0);
}

UNet small_unet() {
  UNet model(UNetConfig{3, 1, 8, 2});
  model.init(5);
  // Non-zero biases so the fused bias is exercised too.
  for (const ParamInfo& p : model.params().infos())
    if (!p.decays)
      for (std::size_t i = 0; i < p.shape.numel(); ++i) model.params().values()[p.offset + i] = 0.01f * (i % 7) - 0.02f;
  return model;
}

TEST(Conv3x3Bf16, WholeUNetPredictStaysCloseToFp32AndTrainingForwardIsUntouched) {
  if (!detail::conv3x3_bf16_available()) GTEST_SKIP() << "this CPU has no AVX-512 BF16: no bf16 path to test";
  UNet model = small_unet();
  const Tensor x = activations(Shape{2, 3, 16, 40}, 9);
  Tensor y32, y16, yf;
  {
    PrecisionGuard p(InferencePrecision::fp32);
    model.predict(x, y32);
  }
  {
    PrecisionGuard p(InferencePrecision::bf16);
    testhook::ScopedIsa isa(Isa::avx512_bf16);
    model.predict(x, y16);
    model.forward(x, yf);  // training's forward pass stays fp32, bit for bit
  }
  ASSERT_EQ(y16.shape(), y32.shape());
  double max_diff = 0, max_ref = 0, sum_diff = 0;
  for (std::size_t i = 0; i < y32.numel(); ++i) {
    const double d = std::abs(static_cast<double>(y16.data()[i]) - y32.data()[i]);
    max_diff = std::max(max_diff, d), sum_diff += d;
    max_ref = std::max(max_ref, static_cast<double>(std::abs(y32.data()[i])));
    EXPECT_EQ(yf.data()[i], y32.data()[i]) << "forward() changed under bf16 inference at " << i;
  }
  // Ten 3x3 convolutions in series, each within 2^-7 of its magnitude: allow 10 x 2^-8 of the
  // output's scale for the worst cell (errors of random sign grow more slowly than that).
  const double rel = max_diff / max_ref;
  std::printf("[ measured ] UNet base 8 depth 2, bf16 vs fp32 predict: max |diff| / max |y| %.2e, mean |diff| %.2e\n",
              rel, sum_diff / y32.numel());
  EXPECT_GT(max_diff, 0.0) << "bit-identical to fp32: bf16 did not run";
  EXPECT_LT(rel, 10 * 0x1p-8);
}

TEST(InferencePrecision, FallsBackToFp32WithOneLineWhenTheCpuLacksBf16) {
  UNet model = small_unet();
  const Tensor x = activations(Shape{1, 3, 16, 24}, 11);
  Tensor y32, y;
  {
    PrecisionGuard p(InferencePrecision::fp32);
    model.predict(x, y32);
  }
  PrecisionGuard p(InferencePrecision::bf16);
  testhook::force_bf16_unsupported(true);
  EXPECT_FALSE(bf16_supported());
  EXPECT_EQ(effective_inference_precision(), InferencePrecision::fp32);
  testhook::force_bf16_unsupported(true);  // re-arm the message for the predict calls below
  ::testing::internal::CaptureStderr();
  model.predict(x, y);
  model.predict(x, y);
  const std::string err = ::testing::internal::GetCapturedStderr();
  testhook::force_bf16_unsupported(false);
  EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << err;
  EXPECT_NE(err.find("bf16"), std::string::npos) << err;
  EXPECT_NE(err.find("fp32"), std::string::npos) << err;
  ASSERT_EQ(y.shape(), y32.shape());
  for (std::size_t i = 0; i < y.numel(); ++i) ASSERT_EQ(y.data()[i], y32.data()[i]) << "at " << i;
}

TEST(InferencePrecision, ParsesFp32AndBf16AndRejectsTheRest) {
  EXPECT_EQ(parse_inference_precision("fp32", "f"), InferencePrecision::fp32);
  EXPECT_EQ(parse_inference_precision("bf16", "f"), InferencePrecision::bf16);
  EXPECT_THROW(parse_inference_precision("fp16", "f"), std::exception);
  EXPECT_STREQ(to_string(InferencePrecision::bf16), "bf16");
}

}  // namespace
}  // namespace lidarsim::nn
