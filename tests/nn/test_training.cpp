// Training works end to end: a tiny UNet (base 4, depth 2) on a tiny fixed batch drives the
// masked loss down >= 100x with Adam, SGD also decreases it, and two runs with the same seed
// (and the same thread count) end with byte-identical parameters.
#include <gtest/gtest.h>

#include <cstdio>
#include <cstdlib>
#include <cmath>
#include <cstring>

#include "nn/loss.h"
#include "nn/optim.h"
#include "nn/unet.h"
#include "reference.h"

namespace lidarsim::nn {
namespace {

struct Batch {
  Tensor x, target, mask;
};

// Smooth input fields (like range images, unlike white noise) and a target that is a fixed
// nonlinear function of them, on ~70 % of the cells.
Batch tiny_batch() {
  Batch b;
  b.x = Tensor(2, 3, 12, 20);
  b.target = Tensor(2, 1, 12, 20);
  b.mask = Tensor(2, 1, 12, 20);
  const Tensor u = reference::random_tensor(b.target.shape(), 101);
  for (int n = 0; n < 2; ++n)
    for (int y = 0; y < 12; ++y)
      for (int x = 0; x < 20; ++x) {
        for (int c = 0; c < 3; ++c)
          b.x.at(n, c, y, x) = std::sin(0.3f * (c + 1) * x + 0.5f * (n + 1) * y + 1.7f * c + n);
        b.target.at(n, 0, y, x) = 0.5f * b.x.at(n, 0, y, x) - 0.3f * b.x.at(n, 1, y, x) * b.x.at(n, 2, y, x) + 0.2f;
        b.mask.at(n, 0, y, x) = u.at(n, 0, y, x) > -0.4f ? 1.f : 0.f;
      }
  return b;
}

struct TrainRun {
  std::vector<double> losses;  // data term per step
  std::vector<float> params;
};

TrainRun train(OptimizerKind kind, float lr, int steps, std::uint64_t seed) {
  const Batch b = tiny_batch();
  UNet model(UNetConfig{3, 1, 4, 2});
  model.init(seed);
  OptimizerConfig oc;
  oc.kind = kind;
  oc.lr = lr;
  Optimizer opt(oc, model.params().size());
  TrainRun run;
  Tensor y, dy;
  for (int s = 0; s < steps; ++s) {
    model.params().zero_grads();
    model.forward(b.x, y);
    const LossParts l = masked_mse(y, b.target, b.mask, &dy);
    model.backward(dy);
    l2_penalty(model.params(), 1e-6f, true);
    opt.step(model.params());
    run.losses.push_back(l.data);
  }
  run.params.assign(model.params().values(), model.params().values() + model.params().size());
  return run;
}

TEST(Training, AdamDrivesTheMaskedLossDownAtLeast100x) {
  // Base 4 is narrow: some seeds lose most units to dead ReLUs and stall (measured over 400 steps
  // at lr 1e-2: seed 1 56x, seeds 2-6 293x-1258x; base 8 gives 1e5x). Seed 3 gives ~1000x here.
  const TrainRun r = train(OptimizerKind::Adam, 1e-2f, 400, 3);
  const double best = *std::min_element(r.losses.begin(), r.losses.end());
  std::printf("[ measured ] Adam: loss %.4g -> %.4g (best %.4g), ratio %.0f\n", r.losses.front(), r.losses.back(), best,
              r.losses.front() / r.losses.back());
  EXPECT_GE(r.losses.front() / r.losses.back(), 100.0);
}

TEST(Training, SgdWithMomentumAlsoDecreasesTheLoss) {
  const TrainRun r = train(OptimizerKind::Sgd, 1e-2f, 100, 3);
  std::printf("[ measured ] SGD: loss %.4g -> %.4g\n", r.losses.front(), r.losses.back());
  EXPECT_LT(r.losses.back(), 0.5 * r.losses.front());
}

TEST(Training, SameSeedGivesByteIdenticalParametersAndAnotherSeedDoesNot) {
  const TrainRun a = train(OptimizerKind::Adam, 1e-2f, 30, 7), b = train(OptimizerKind::Adam, 1e-2f, 30, 7),
                 c = train(OptimizerKind::Adam, 1e-2f, 30, 8);
  ASSERT_EQ(a.params.size(), b.params.size());
  EXPECT_EQ(std::memcmp(a.params.data(), b.params.data(), a.params.size() * sizeof(float)), 0);
  EXPECT_NE(std::memcmp(a.params.data(), c.params.data(), a.params.size() * sizeof(float)), 0);
}

}  // namespace
}  // namespace lidarsim::nn

namespace lidarsim::nn {
namespace {

// Large enough that every layer takes its parallel path: two backward passes with the same
// thread count give the same gradient bytes (no float atomics, fixed reduction order).
TEST(Determinism, ParallelForwardBackwardIsBitIdenticalAcrossRuns) {
  UNet model(UNetConfig{3, 1, 8, 2});
  model.init(11);
  const Tensor x = reference::random_tensor(Shape{2, 3, 64, 96}, 12);
  const Tensor dy = reference::random_tensor(Shape{2, 1, 64, 96}, 13);
  std::vector<float> first;
  for (int run = 0; run < 2; ++run) {
    Tensor y;
    model.params().zero_grads();
    model.forward(x, y);
    model.backward(dy);
    const float* g = model.params().grads();
    if (run == 0) {
      first.assign(g, g + model.params().size());
    } else {
      EXPECT_EQ(std::memcmp(first.data(), g, first.size() * sizeof(float)), 0);
    }
  }
}

}  // namespace
}  // namespace lidarsim::nn
