// The AMX bf16 kernel (nn/conv3x3_amx.h) against the fp32 direct conv, with the bound of
// test_conv3x3_bf16.cpp (2^-7 x sum |w| |x| over the window, plus fp32 order), and against the
// AVX-512 BF16 kernel: both multiply the same bf16-rounded factors (products exact in fp32), so
// they may differ only by the order of the fp32 sums. Shapes: input channels 3, 16, 48 (not a
// multiple of the 32-channel tile step) and 96 as a concat (split inside a step), outputs 1, 16,
// 40 (partial 16-channel tiles, an odd tile), widths 1, 17, 64, 1000 (partial 16- and 64-pixel
// blocks, rows wrapping inside a block), heights 1 and 5 (the input staged whole) and 16-21 (staged
// per band of rows), batches 1 and 3.
#include <gtest/gtest.h>
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "bf16_bound.h"
#include "conv_path.h"
#include "nn/conv3x3_amx.h"
#include "nn/conv3x3_bf16.h"
#include "nn/cpu_features.h"
#include "nn/layers.h"
#include "nn/precision.h"
#include "nn/unet.h"

namespace lidarsim::nn {
namespace {

using namespace bf16_bound;

constexpr const char* kNoAmx = "this CPU (or LIDARSIM_ISA) has no AMX-BF16: no AMX path to test";

struct AmxCase {
  int n, ca, cb, co, h, w;  // input = concat of ca and cb channels (cb 0: plain)
};

const AmxCase kAmxCases[] = {{1, 3, 0, 16, 5, 1000}, {3, 3, 0, 1, 5, 17},   {1, 16, 0, 16, 5, 64},  {3, 16, 0, 40, 1, 17},
                       {1, 48, 0, 40, 5, 17},  {1, 48, 0, 16, 1, 1000}, {3, 48, 48, 40, 5, 64}, {1, 48, 48, 1, 1, 1},
                       {3, 16, 0, 1, 1, 1},    {1, 20, 28, 40, 5, 17},  {1, 3, 0, 40, 1, 64},   {3, 48, 48, 16, 5, 1},
                       // At least 16 rows: staged per band of 8 rows (the last one partial here).
                       {1, 3, 0, 16, 21, 64},  {3, 16, 0, 40, 17, 17},  {1, 48, 48, 40, 19, 33}, {1, 16, 0, 1, 16, 1},
                       // 4 and 8 values per staged pixel (ci <= 4, ci <= 8).
                       {1, 4, 0, 16, 17, 17},  {3, 5, 3, 16, 5, 33},    {1, 7, 0, 9, 16, 20}};

std::string name(const AmxCase& c) {
  return "n " + std::to_string(c.n) + " ci " + std::to_string(c.ca) + "+" + std::to_string(c.cb) + " co " +
         std::to_string(c.co) + " " + std::to_string(c.h) + "x" + std::to_string(c.w);
}

struct Inputs {
  Tensor a, b;
  std::vector<float> w, bias;
  explicit Inputs(const AmxCase& c)
      : a(activations(Shape{c.n, c.ca, c.h, c.w}, 1)),
        b(c.cb ? activations(Shape{c.n, c.cb, c.h, c.w}, 2) : Tensor()),
        w(he_weights(c.co, c.ca + c.cb, 3)),
        bias(static_cast<std::size_t>(c.co)) {
    for (int o = 0; o < c.co; ++o) bias[o] = 0.05f * (o % 5) - 0.1f;
  }
  std::vector<double> mag(const AmxCase& c) const {
    std::vector<const Tensor*> ins{&a};
    if (c.cb) ins.push_back(&b);
    return magnitude(ins, w, c.co);
  }
};

Tensor run_amx(const AmxCase& c, const Inputs& in, bool with_bias, bool relu) {
  Tensor y(c.n, c.co, c.h, c.w);
  detail::conv3x3_amx_forward_cat(y.data(), in.a.data(), c.ca, c.cb ? in.b.data() : nullptr, c.cb, c.n, c.h, c.w,
                                  in.w.data(), with_bias ? in.bias.data() : nullptr, c.co, relu);
  return y;
}

// The fp32 reference: the direct kernel through the layer function (as test_conv3x3_bf16.cpp).
Tensor run_fp32(const AmxCase& c, const Inputs& in, bool with_bias, bool relu) {
  conv_paths::Conv3x3PathGuard direct(detail::Conv3x3Path::direct);
  Tensor y;
  const float* bias = with_bias ? in.bias.data() : nullptr;
  if (c.cb)
    conv2d_cat_forward(y, in.a, in.b, in.w.data(), bias, c.co, relu);
  else
    conv2d_forward(y, in.a, in.w.data(), bias, c.co, 3, 1, relu);
  return y;
}

// Worst |got - ref| / (scale x mag + 2^-20 (mag + |bias|)) over the outputs.
double worst_ratio(const AmxCase& c, const Tensor& got, const Tensor& ref, const std::vector<double>& mag,
                   const std::vector<float>& bias, bool with_bias, double scale) {
  double worst = 0;
  const std::size_t plane = static_cast<std::size_t>(c.h) * c.w;
  for (std::size_t i = 0; i < ref.numel(); ++i) {
    const double b = with_bias ? std::abs(bias[i / plane % c.co]) : 0.0;
    const double d = std::abs(static_cast<double>(got.data()[i]) - ref.data()[i]);
    worst = std::max(worst, d / (scale * mag[i] + 0x1p-20 * (mag[i] + b) + 1e-30));
  }
  return worst;
}

TEST(Conv3x3Amx, MatchesFp32WithinBf16RoundingOnOddSizesAndConcats) {
  if (!detail::conv3x3_amx_available()) GTEST_SKIP() << kNoAmx;
  double worst = 0;
  for (const AmxCase& c : kAmxCases) {
    const Inputs in(c);
    const std::vector<double> mag = in.mag(c);
    for (bool with_bias : {false, true})
      for (bool relu : {false, true}) {
        SCOPED_TRACE(name(c) + " bias " + std::to_string(with_bias) + " relu " + std::to_string(relu));
        const Tensor y = run_amx(c, in, with_bias, relu), ref = run_fp32(c, in, with_bias, relu);
        const double r = worst_ratio(c, y, ref, mag, in.bias, with_bias, 0x1p-7);
        EXPECT_LE(r, 1.0) << "|amx - fp32| exceeds 2^-7 of the dot product's magnitude";
        if (c.h * c.w > 1 && !relu) {
          EXPECT_NE(std::memcmp(y.data(), ref.data(), y.numel() * 4), 0) << "bit-identical to fp32: bf16 did not run";
        }
        worst = std::max(worst, r);
      }
  }
  std::printf("[ measured ] amx vs fp32 conv: worst |diff| / bound %.3f\n", worst);
}

// Same factors as the AVX-512 BF16 kernel (same rounding): the outputs differ only by the order
// of two fp32 sums of K = 9 ci + 1 terms, each within K 2^-24 of its magnitude.
TEST(Conv3x3Amx, AgreesWithTheAvx512Bf16KernelUpToSumOrder) {
  if (!detail::conv3x3_amx_available()) GTEST_SKIP() << kNoAmx;
  double worst = 0;
  for (const AmxCase& c : kAmxCases) {
    SCOPED_TRACE(name(c));
    const Inputs in(c);
    const std::vector<double> mag = in.mag(c);
    Tensor y16(c.n, c.co, c.h, c.w);
    detail::conv3x3_bf16_forward_cat(y16.data(), in.a.data(), c.ca, c.cb ? in.b.data() : nullptr, c.cb, c.n, c.h,
                                     c.w, in.w.data(), in.bias.data(), c.co, false);
    const Tensor y = run_amx(c, in, true, false);
    const double k = 9.0 * (c.ca + c.cb) + 1;
    const double r = worst_ratio(c, y, y16, mag, in.bias, true, 2 * k * 0x1p-24);
    EXPECT_LE(r, 1.0) << "AMX and AVX-512 BF16 differ by more than the order of their sums";
    worst = std::max(worst, r);
  }
  std::printf("[ measured ] amx vs avx512_bf16 conv: worst |diff| / sum-order bound %.3f\n", worst);
}

TEST(Conv3x3Amx, SameBitsAtOneAndTwoThreads) {
  if (!detail::conv3x3_amx_available()) GTEST_SKIP() << kNoAmx;
  const int saved = omp_get_max_threads();
  // The large case keeps both threads busy (a worker that wakes late may find no task left).
  for (const AmxCase& c : {AmxCase{3, 48, 48, 40, 5, 64}, AmxCase{1, 3, 0, 16, 5, 1000}, AmxCase{2, 40, 24, 48, 32, 512}}) {
    SCOPED_TRACE(name(c));
    const Inputs in(c);
    omp_set_num_threads(1);
    const Tensor y1 = run_amx(c, in, true, true);
    omp_set_num_threads(2);
    for (int run = 0; run < 3; ++run) {
      const Tensor y2 = run_amx(c, in, true, true);
      EXPECT_EQ(std::memcmp(y1.data(), y2.data(), y1.numel() * 4), 0) << "run " << run;
    }
  }
  omp_set_num_threads(saved);
}

// A whole predict in bf16 with AMX against fp32, with the bound of test_conv3x3_bf16.cpp's UNet
// test; and not the AVX-512 BF16 kernel's bits (AMX ran).
TEST(Conv3x3Amx, WholeUNetPredictStaysCloseToFp32) {
  if (!detail::conv3x3_amx_available()) GTEST_SKIP() << kNoAmx;
  UNet model(UNetConfig{3, 1, 8, 2});
  model.init(5);
  for (const ParamInfo& p : model.params().infos())
    if (!p.decays)
      for (std::size_t i = 0; i < p.shape.numel(); ++i) model.params().values()[p.offset + i] = 0.01f * (i % 7) - 0.02f;
  const Tensor x = activations(Shape{2, 3, 16, 40}, 9);
  Tensor y32, yamx, y16;
  {
    PrecisionGuard p(InferencePrecision::fp32);
    model.predict(x, y32);
  }
  {
    PrecisionGuard p(InferencePrecision::bf16);
    model.predict(x, yamx);
    testhook::ScopedIsa isa(Isa::avx512_bf16);
    model.predict(x, y16);
  }
  ASSERT_EQ(yamx.shape(), y32.shape());
  double max_diff = 0, max_ref = 0;
  for (std::size_t i = 0; i < y32.numel(); ++i) {
    max_diff = std::max(max_diff, std::abs(static_cast<double>(yamx.data()[i]) - y32.data()[i]));
    max_ref = std::max(max_ref, static_cast<double>(std::abs(y32.data()[i])));
  }
  const double rel = max_diff / max_ref;
  std::printf("[ measured ] UNet base 8 depth 2, amx bf16 vs fp32 predict: max |diff| / max |y| %.2e\n", rel);
  EXPECT_LT(rel, 10 * 0x1p-8);
  EXPECT_NE(std::memcmp(yamx.data(), y16.data(), y16.numel() * 4), 0) << "the AVX-512 BF16 bits: AMX did not run";
}

}  // namespace
}  // namespace lidarsim::nn
