// The whole UNet with the masked MSE + L2 loss against central differences (eps 1e-6) of the
// double-precision reference UNet (reference.h, written from nn/unet.h's comment), for EVERY
// parameter, at odd input sizes with batch 2. Error = max |analytic - numeric| / max |numeric|,
// tolerance 1e-4. A fault injected into one layer's backward must push the error above 1e-2.
#include <gtest/gtest.h>

#include <cstdio>
#include <cstring>

#include "common/error.h"
#include "conv_path.h"
#include "nn/heads.h"
#include "nn/layers.h"
#include "nn/loss.h"
#include "nn/optim.h"
#include "nn/unet.h"
#include "nn/winograd.h"
#include "reference.h"
#include "reference_losses.h"

namespace lidarsim::nn {
namespace {

using namespace reference;

struct UnetCase {
  UNetConfig cfg;
  Shape x;
  float lambda;
};

struct Result {
  double forward = 0, grad = 0;
};

Result check_unet(const UnetCase& c, detail::Conv3x3Path path = detail::Conv3x3Path::direct) {
  conv_paths::Conv3x3PathGuard guard(path);
  UNet model(c.cfg);
  model.init(7);
  // Non-zero biases so their gradients are exercised through every ReLU pattern.
  ParamArena& arena = model.params();
  const std::vector<float> bias_noise = random_vector(arena.size(), 8, 0.1f);
  for (const ParamInfo& p : arena.infos())
    if (!p.decays)
      for (std::size_t i = 0; i < p.shape.numel(); ++i) arena.values()[p.offset + i] = bias_noise[p.offset + i];
  // Row-affine gains and offsets away from 1 and 0, so every term of their gradient shows.
  for (const ParamInfo& p : arena.infos())
    if (p.name.rfind("row_affine/", 0) == 0)
      for (std::size_t i = 0; i < p.shape.numel(); ++i)
        arena.values()[p.offset + i] = p.decay_center + 3 * bias_noise[p.offset + i];
  // With a lookup base the head starts at zero, which would hide every gradient below it.
  for (const ParamInfo& p : arena.infos())
    if (c.cfg.lookup.classes > 0 && p.name == "head/weight")
      for (std::size_t i = 0; i < p.shape.numel(); ++i) arena.values()[p.offset + i] = 0.5f * bias_noise[p.offset + i];

  const Tensor x = random_tensor(c.x, 9);
  const Shape ys{c.x.n, c.cfg.out_channels, c.x.h, c.x.w};
  const Tensor target = random_tensor(ys, 10);
  Tensor mask(ys);
  const Tensor u = random_tensor(ys, 11);
  for (std::size_t i = 0; i < mask.numel(); ++i) mask.data()[i] = u.data()[i] > -0.2f ? 1.f : 0.f;  // ~60 %

  // With heads: one [N, 1, H, W] target and mask per head (channel k of the tensors above; the
  // return head's target thresholded to 0 / 1; the spread head shares the mean's cells).
  const int k = c.cfg.out_channels;
  const Shape one{c.x.n, 1, c.x.h, c.x.w};
  std::vector<Tensor> head_target(k, Tensor(one)), head_mask(k, Tensor(one));
  for (int h = 0; h < k && !c.cfg.heads.empty(); ++h) {
    const bool spread = c.cfg.heads[h] == HeadKind::log_scale_gaussian || c.cfg.heads[h] == HeadKind::log_scale_laplace;
    const int src = spread ? 0 : h;
    for (int n = 0; n < c.x.n; ++n)
      for (std::size_t i = 0; i < one.plane(); ++i) {
        float t = target.channel(n, src)[i];
        if (c.cfg.heads[h] == HeadKind::return_logit) t = t > 0 ? 1.f : 0.f;
        head_target[h].image(n)[i] = t;
        head_mask[h].image(n)[i] = mask.channel(n, src)[i];
      }
  }
  std::vector<HeadTarget> head_targets;
  for (int h = 0; h < k; ++h) head_targets.push_back({&head_target[h], &head_mask[h], 1.f, 0});

  Tensor y, dy;
  model.forward(x, y);
  arena.zero_grads();
  if (c.cfg.heads.empty())
    masked_mse(y, target, mask, &dy);
  else
    heads_loss(c.cfg.heads, y, head_targets, &dy);
  model.backward(dy);
  l2_penalty(arena, c.lambda, true);

  std::vector<double> p(arena.values(), arena.values() + arena.size());
  const DT xd = from(x);
  double valid = 0;
  for (float m : mask) valid += m;
  // The heads' losses in double (reference_losses.h); the spread is fitted around a detached mean.
  auto heads_data = [&](const DT& out, const DT& detached) {
    double total = 0;
    for (int h = 0; h < k; ++h) {
      double s = 0, v = 0;
      for (int n = 0; n < c.x.n; ++n)
        for (int yy = 0; yy < c.x.h; ++yy)
          for (int xx = 0; xx < c.x.w; ++xx) {
            const std::size_t i = (std::size_t(n) * c.x.h + yy) * c.x.w + xx;
            if (head_mask[h].data()[i] == 0.f) continue;
            const double o = out.at(n, h, yy, xx), t = head_target[h].data()[i], mu = detached.at(n, 0, yy, xx);
            switch (c.cfg.heads[h]) {
              case HeadKind::mean: s += (o - t) * (o - t); break;
              case HeadKind::return_logit: s += bce_cell(o, t); break;
              case HeadKind::log_scale_gaussian: s += gaussian_nll_cell(mu, o, t, -7, 3); break;
              case HeadKind::log_scale_laplace: s += laplace_nll_cell(mu, o, t, -7, 3); break;
              case HeadKind::zero_logit:  // trains its own output row only (SpreadHead's same-bits tests)
                ADD_FAILURE() << "no reference loss for zero_logit here: its trunk input is detached";
                break;
              case HeadKind::count: break;
            }
            ++v;
          }
      total += s / std::max(v, 1.0);
    }
    return total;
  };
  const DT detached = unet(model, p, xd);
  auto loss = [&] {
    const DT out = unet(model, p, xd);
    double data = 0;
    if (!c.cfg.heads.empty()) data = heads_data(out, detached) * valid;  // divided by valid below
    for (std::size_t i = 0; i < out.v.size() && c.cfg.heads.empty(); ++i) {
      const double d = out.v[i] - target.data()[i];
      data += mask.data()[i] * d * d;
    }
    double l2 = 0;
    for (const ParamInfo& info : arena.infos())
      if (info.decays)
        for (std::size_t i = 0; i < info.shape.numel(); ++i) {
          const double d = p[info.offset + i] - info.decay_center;
          l2 += d * d;
        }
    return data / valid + c.lambda * l2;
  };
  Result r;
  r.forward = max_rel_error(y.data(), unet(model, p, xd).v);
  std::vector<double> numeric = numeric_gradient(p, loss);
  // Frozen parameters (the fitted lookup table: step 0) get no gradient by design.
  for (const ParamInfo& info : arena.infos())
    if (info.lr_scale == 0.f) std::fill_n(numeric.begin() + info.offset, info.shape.numel(), 0.0);
  r.grad = max_rel_error(arena.grads(), numeric);
  std::printf("[ measured ] UNet %s: forward error %.2e, gradient error %.2e over %zu parameters\n",
              c.x.str().c_str(), r.forward, r.grad, arena.size());
  return r;
}

const UnetCase kOdd7x9{{3, 1, 2, 2}, {2, 3, 7, 9}, 1e-2f};
const UnetCase kOdd5x11{{2, 2, 3, 2}, {2, 2, 5, 11}, 1e-2f};
const UnetCase kRowAffine7x9{{3, 2, 2, 2, 7}, {2, 3, 7, 9}, 1e-2f};  // two outputs, a gain and offset each per row
// Lookup base on 3 "class" channels from 1 and range in channel 0 (random inputs: cells with
// range <= 0 are empty, cells with no class channel above 0.5 take the no-group row).
const UnetCase kLookup7x9{{4, 1, 2, 2, 0, {3, 1, 0, 4, 0.25f, 7}}, {2, 4, 7, 9}, 1e-2f};
// Three heads (mean, return logit, Laplace log-scale) over the lookup base and the row affine:
// the base goes onto channel 0 only, each channel has its own loss.
const UnetCase kHeads7x9{{4, 3, 2, 2, 7, {3, 1, 0, 4, 0.25f, 7}, {HeadKind::mean, HeadKind::return_logit, HeadKind::log_scale_laplace}},
                     {2, 4, 7, 9},
                     1e-2f};
const UnetCase kHeadsGauss5x11{{2, 3, 3, 2, 0, {}, {HeadKind::mean, HeadKind::log_scale_gaussian, HeadKind::return_logit}},
                           {2, 2, 5, 11},
                           1e-2f};

TEST(UNetGradCheck, OddSize7x9Batch2AllParametersMatchFiniteDifferences) {
  const Result r = check_unet(kOdd7x9);
  EXPECT_LT(r.forward, 1e-5);
  EXPECT_LT(r.grad, 1e-4);
}

TEST(UNetGradCheck, OddSize5x11TwoOutputsAllParametersMatchFiniteDifferences) {
  const Result r = check_unet(kOdd5x11);
  EXPECT_LT(r.forward, 1e-5);
  EXPECT_LT(r.grad, 1e-4);
}

TEST(UNetGradCheck, RowAffineLayerAndEveryParameterBelowItMatchFiniteDifferences) {
  const Result r = check_unet(kRowAffine7x9);
  EXPECT_LT(r.forward, 1e-5);
  EXPECT_LT(r.grad, 1e-4);
}

// Every parameter again with the 3x3 convolutions forced onto Winograd F(4x4, 3x3).
TEST(UNetGradCheck, WinogradPathOddSizesAllParametersMatchFiniteDifferences) {
  if (!detail::winograd_available()) GTEST_SKIP() << "built without AVX2 kernels (LIDARSIM_ARCH below x86-64-v3): no Winograd path";
  for (const UnetCase& c : {kOdd7x9, kOdd5x11}) {
    const Result r = check_unet(c, detail::Conv3x3Path::winograd);
    EXPECT_LT(r.forward, 1e-5);
    EXPECT_LT(r.grad, 1e-4);
  }
}

TEST(UNetGradCheck, LookupBaseInputChannelAndEveryTrainedParameterMatchFiniteDifferences) {
  const Result r = check_unet(kLookup7x9);
  EXPECT_LT(r.forward, 1e-5);
  EXPECT_LT(r.grad, 1e-4);
}

TEST(UNetGradCheck, ThreeHeadsEachWithItsLossAndEveryParameterMatchFiniteDifferences) {
  for (const UnetCase& c : {kHeads7x9, kHeadsGauss5x11}) {
    const Result r = check_unet(c);
    EXPECT_LT(r.forward, 1e-5);
    EXPECT_LT(r.grad, 1e-4);
  }
}

TEST(UNet, LookupBaseStartsAsTheTableIsFrozenAndNeedsItsRowCount) {
  UNet model(kLookup7x9.cfg);
  model.init(5);
  ParamArena& a = model.params();
  const ParamInfo& t = a.info(a.find("lookup/table"));
  const ParamInfo& b = a.info(a.find("lookup/beam"));
  EXPECT_EQ(t.shape, (Shape{1, 1, 4, 4}));
  EXPECT_EQ(b.shape, (Shape{1, 1, 7, 1}));
  EXPECT_EQ(t.lr_scale, 0.f);
  EXPECT_FALSE(t.decays);
  EXPECT_EQ(a.info(a.find("enc0.conv1/weight")).shape, (Shape{2, 5, 3, 3}));  // the base is one more input
  const std::vector<float> table = random_vector(16, 21), beam = random_vector(7, 22);
  std::copy(table.begin(), table.end(), a.value(a.find("lookup/table")));
  std::copy(beam.begin(), beam.end(), a.value(a.find("lookup/beam")));
  const Tensor x = random_tensor(Shape{2, 4, 7, 9}, 23);
  Tensor y, base;
  model.forward(x, y);
  lookup_base_forward(base, x, kLookup7x9.cfg.lookup, table.data(), beam.data());
  EXPECT_EQ(std::memcmp(y.data(), base.data(), y.numel() * sizeof(float)), 0);  // head 0: exactly the table
  EXPECT_THROW(model.forward(random_tensor(Shape{2, 4, 8, 9}, 3), y), Error);
  // A training step leaves the fitted table where it is.
  Optimizer opt(OptimizerConfig{}, a.size());
  Tensor dy = random_tensor(y.shape(), 24);
  a.zero_grads();
  model.backward(dy);
  opt.step(a);
  EXPECT_EQ(std::memcmp(a.value(a.find("lookup/table")), table.data(), table.size() * sizeof(float)), 0);
}

TEST(UNet, RowAffineStartsAsTheIdentityAndNeedsItsRowCount) {
  UNet plain(UNetConfig{3, 1, 4, 2}), rows(UNetConfig{3, 1, 4, 2, 8});
  plain.init(5);
  rows.init(5);
  const ParamArena& a = rows.params();
  const ParamInfo& g = a.info(a.find("row_affine/gain"));
  EXPECT_EQ(g.shape, (Shape{1, 1, 8, 1}));
  EXPECT_EQ(g.decay_center, 1.f);
  // The same seed gives the same network below the layer, and the layer starts as the identity.
  EXPECT_EQ(std::memcmp(plain.params().values(), a.values(), plain.params().size() * sizeof(float)), 0);
  const Tensor x = random_tensor(Shape{1, 3, 8, 12}, 3);
  Tensor y0, y1;
  plain.forward(x, y0);
  rows.forward(x, y1);
  EXPECT_EQ(std::memcmp(y0.data(), y1.data(), y0.numel() * sizeof(float)), 0);
  EXPECT_THROW(rows.forward(random_tensor(Shape{1, 3, 12, 12}, 3), y1), Error);
}

TEST(UNetGradCheck, DetectsAWrongIndexInsideTheNetwork) {
  testhook::fault = testhook::Fault::max_pool;
  const Result r = check_unet(kOdd7x9);
  testhook::fault = testhook::Fault::none;
  EXPECT_GT(r.grad, 1e-2);
}

TEST(UNet, ForwardFlopsOfUnetRefAre6Point07Giga) {
  UNet model(UNetConfig{});
  EXPECT_NEAR(model.forward_flops(1, 64, 1024) / 1e9, 6.07, 0.01);
}

TEST(UNet, ParameterNamesAndLayoutsFollowTheHeader) {
  UNet model(UNetConfig{3, 1, 16, 4});
  const ParamArena& a = model.params();
  ASSERT_GE(a.find("enc0.conv1/weight"), 0);
  EXPECT_EQ(a.info(a.find("enc0.conv1/weight")).shape, (Shape{16, 3, 3, 3}));
  EXPECT_EQ(a.info(a.find("enc4.conv2/weight")).shape, (Shape{256, 256, 3, 3}));
  EXPECT_EQ(a.info(a.find("dec3.up/weight")).shape, (Shape{256, 128, 2, 2}));
  EXPECT_EQ(a.info(a.find("dec0.conv1/weight")).shape, (Shape{16, 32, 3, 3}));
  EXPECT_EQ(a.info(a.find("head/weight")).shape, (Shape{1, 16, 1, 1}));
  EXPECT_EQ(a.info(a.find("head/bias")).shape, (Shape{1, 1, 1, 1}));
  EXPECT_FALSE(a.info(a.find("head/bias")).decays);
  EXPECT_TRUE(a.info(a.find("dec3.up/weight")).decays);
}

TEST(UNet, HeInitHasTheFanInStandardDeviationAndZeroBiases) {
  UNet model(UNetConfig{3, 1, 16, 4});
  model.init(42);
  const ParamArena& a = model.params();
  const ParamInfo& w = a.info(a.find("enc4.conv2/weight"));  // 589824 values, fan_in 2304
  double s = 0, s2 = 0;
  const std::size_t n = w.shape.numel();
  for (std::size_t i = 0; i < n; ++i) {
    s += a.values()[w.offset + i];
    s2 += double(a.values()[w.offset + i]) * a.values()[w.offset + i];
  }
  const double mean = s / n, sd = std::sqrt(s2 / n - mean * mean);
  const double expect = std::sqrt(2.0 / 2304);
  EXPECT_NEAR(mean, 0.0, 5 * expect / std::sqrt(double(n)));  // 5 standard errors
  EXPECT_NEAR(sd / expect, 1.0, 0.01);                        // ~11 standard errors of sd
  const ParamInfo& b = a.info(a.find("enc4.conv2/bias"));
  for (std::size_t i = 0; i < b.shape.numel(); ++i) EXPECT_EQ(a.values()[b.offset + i], 0.f);
}

TEST(UNet, InitIsDeterministicPerSeedAndDiffersBetweenSeeds) {
  UNet a(UNetConfig{3, 1, 4, 2}), b(UNetConfig{3, 1, 4, 2}), c(UNetConfig{3, 1, 4, 2});
  a.init(5);
  b.init(5);
  c.init(6);
  const std::size_t bytes = a.params().size() * sizeof(float);
  EXPECT_EQ(std::memcmp(a.params().values(), b.params().values(), bytes), 0);
  EXPECT_NE(std::memcmp(a.params().values(), c.params().values(), bytes), 0);
}

TEST(UNet, RejectsWrongChannelsTooSmallInputsAndNonFiniteValues) {
  UNet model(UNetConfig{3, 1, 4, 2});
  model.init(1);
  Tensor y;
  EXPECT_THROW(model.forward(Tensor(1, 2, 8, 8), y), Error);
  EXPECT_THROW(model.forward(Tensor(1, 3, 3, 8), y), Error);  // needs H, W >= 4
  Tensor x(1, 3, 8, 8);
  x.at(0, 1, 2, 3) = std::nanf("");
  EXPECT_THROW(model.forward(x, y), Error);
}

TEST(UNet, PredictEqualsForward) {
  UNet model(UNetConfig{3, 1, 4, 2});
  model.init(3);
  const Tensor x = random_tensor(Shape{2, 3, 9, 13}, 4);
  Tensor y1, y2;
  model.forward(x, y1);
  model.predict(x, y2);
  EXPECT_EQ(std::memcmp(y1.data(), y2.data(), y1.numel() * sizeof(float)), 0);
}

}  // namespace
}  // namespace lidarsim::nn
