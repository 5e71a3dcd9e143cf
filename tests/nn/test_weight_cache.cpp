// UNet::predict keeps the derived weights of its convolutions across calls (nn/weight_cache.h).
// On each path (Winograd, direct, bf16): the second predict must hit the cache (Winograd: when
// built to cache U) and give the same bits; after one weight is changed through the parameter arena the next predict must equal a
// fresh model's with the changed weights (and differ from before); and forward() (training,
// never cached) must equal predict() bit for bit in fp32.
#include <gtest/gtest.h>

#include <cstring>
#include <random>
#include <string>

#include "conv_path.h"
#include "nn/precision.h"
#include "nn/unet.h"
#include "nn/weight_cache.h"
#include "nn/winograd.h"

namespace lidarsim::nn {
namespace {

using conv_paths::Conv3x3PathGuard;
using detail::Conv3x3Path;

Tensor cache_input(Shape s) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  Tensor t(s);
  for (float& v : t) v = u(rng);
  return t;
}

bool same_bits(const Tensor& a, const Tensor& b) {
  return a.shape() == b.shape() && std::memcmp(a.data(), b.data(), a.numel() * sizeof(float)) == 0;
}

// The largest 3x3 conv weight: the one most likely to take every path's cached form.
int largest_conv3x3(const ParamArena& p) {
  int best = -1;
  for (int i = 0; i < static_cast<int>(p.infos().size()); ++i) {
    const Shape& s = p.info(i).shape;
    if (s.h == 3 && s.w == 3 && (best < 0 || s.numel() > p.info(best).shape.numel())) best = i;
  }
  return best;
}

struct CachePrecisionGuard {
  explicit CachePrecisionGuard(InferencePrecision p) : old(inference_precision()) { set_inference_precision(p); }
  ~CachePrecisionGuard() { set_inference_precision(old); }
  InferencePrecision old;
};

void check(Conv3x3Path path, InferencePrecision precision) {
  SCOPED_TRACE(std::string(conv_paths::path_name(path)) + " " + to_string(precision));
  Conv3x3PathGuard guard(path);
  CachePrecisionGuard pg(precision);
  const UNetConfig cfg{3, 1, 8, 2};
  UNet model(cfg);
  model.init(7);
  const Tensor x = cache_input(Shape{2, 3, 16, 40});
  Tensor y1, y1b, y2, y3, yf;
  model.predict(x, y1);
  const std::size_t hits = detail::testhook::weight_cache_hits();
  model.predict(x, y1b);
  // Winograd transforms its weights per call, and the GEMM fallback (no AVX-512, or LIDARSIM_ISA=avx2)
  // keeps no derived weights: only the direct kernels cache.
  if (path != Conv3x3Path::winograd && detail::conv3x3_available()) {
    EXPECT_GT(detail::testhook::weight_cache_hits(), hits) << "the second predict did not use the cache";
  }
  EXPECT_TRUE(same_bits(y1, y1b));
  if (precision == InferencePrecision::fp32) {
    model.forward(x, yf);
    EXPECT_TRUE(same_bits(yf, y1)) << "predict differs from forward";
  }

  const int id = largest_conv3x3(model.params());
  ASSERT_GE(id, 0);
  // The centre taps of output channel 0 (over all its inputs): a change that cannot vanish behind a
  // ReLU the way one tap of a dead channel can.
  for (int c = 0; c < model.params().info(id).shape.c; ++c) model.params().value(id)[c * 9 + 4] += 0.5f;
  model.predict(x, y2);
  UNet fresh(cfg);
  std::memcpy(fresh.params().values(), model.params().values(), model.params().size() * sizeof(float));
  fresh.predict(x, y3);
  EXPECT_TRUE(same_bits(y2, y3)) << "a changed weight was served from the cache";
  EXPECT_FALSE(same_bits(y2, y1)) << "the changed weight did not change the prediction";
}

TEST(WeightCache, PredictReusesDerivedWeightsAndNeverServesChangedOnes) {
  check(Conv3x3Path::winograd, InferencePrecision::fp32);
  check(Conv3x3Path::direct, InferencePrecision::fp32);
  if (bf16_supported()) check(Conv3x3Path::direct, InferencePrecision::bf16);
}

}  // namespace
}  // namespace lidarsim::nn
