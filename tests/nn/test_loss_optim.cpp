// Masked MSE, the L2 term and the optimizers on cases worked out by hand.
#include <gtest/gtest.h>

#include <cmath>

#include "common/error.h"
#include "nn/loss.h"
#include "nn/optim.h"

namespace lidarsim::nn {
namespace {

Tensor make(std::initializer_list<float> v) {
  Tensor t(1, 1, 1, static_cast<int>(v.size()));
  std::copy(v.begin(), v.end(), t.begin());
  return t;
}

TEST(MaskedMse, AveragesOnlyValidCellsAndItsGradientIsZeroElsewhere) {
  const Tensor pred = make({1, 2, 3, 4}), target = make({0, 0, 1, 100}), mask = make({1, 1, 1, 0});
  Tensor d;
  const LossParts l = masked_mse(pred, target, mask, &d);
  EXPECT_EQ(l.valid, 3);
  EXPECT_DOUBLE_EQ(l.data, (1.0 + 4.0 + 4.0) / 3.0);  // the masked 96^2 does not count
  EXPECT_FLOAT_EQ(d.data()[0], 2.f * 1 / 3);
  EXPECT_FLOAT_EQ(d.data()[1], 2.f * 2 / 3);
  EXPECT_FLOAT_EQ(d.data()[2], 2.f * 2 / 3);
  EXPECT_EQ(d.data()[3], 0.f);
}

TEST(MaskedMse, EmptyMaskGivesZeroLossNotNaN) {
  const Tensor p = make({1, 2}), t = make({3, 4}), m = make({0, 0});
  EXPECT_EQ(masked_mse(p, t, m, nullptr).data, 0.0);
}

TEST(MaskedMse, NonFiniteTargetInAValidCellAndShapeMismatchAreErrors) {
  const Tensor p = make({1, 2}), m = make({1, 1});
  EXPECT_THROW(masked_mse(p, make({1, std::nanf("")}), m, nullptr), Error);
  EXPECT_THROW(masked_mse(p, make({1, 2, 3}), m, nullptr), Error);
  // A NaN in a masked-out cell is ignored: no return there, no target.
  EXPECT_NO_THROW(masked_mse(p, make({1, std::nanf("")}), make({1, 0}), nullptr));
}

TEST(L2Penalty, SumsSquaredWeightsOnlyAndAddsTwoLambdaW) {
  ParamArena a;
  a.add("l/weight", Shape{1, 1, 1, 2}, true);
  a.add("l/bias", Shape{1, 1, 1, 1}, false);
  a.finalize();
  a.values()[0] = 3;
  a.values()[1] = -4;
  a.values()[2] = 10;  // bias: not regularised
  const double l2 = l2_penalty(a, 0.5f, true);
  EXPECT_DOUBLE_EQ(l2, 0.5 * 25);
  EXPECT_FLOAT_EQ(a.grads()[0], 3.f);
  EXPECT_FLOAT_EQ(a.grads()[1], -4.f);
  EXPECT_EQ(a.grads()[2], 0.f);
}

ParamArena one_param(float value, float grad) {
  ParamArena a;
  a.add("p/weight", Shape{1, 1, 1, 1}, true);
  a.finalize();
  a.values()[0] = value;
  a.grads()[0] = grad;
  return a;
}

TEST(Adam, FirstStepMovesByLrTimesSignAndSecondFollowsTorchFormula) {
  OptimizerConfig c;
  c.lr = 0.1f;
  Optimizer opt(c, 1);
  ParamArena a = one_param(1.f, 0.5f);
  opt.step(a);
  // Step 1: m_hat = g, v_hat = g^2, update = lr g / (|g| + eps).
  EXPECT_NEAR(a.values()[0], 1.f - 0.1f * 0.5f / (0.5f + 1e-8f), 1e-7);
  a.grads()[0] = -1.f;
  opt.step(a);
  const double m = 0.9 * (0.1 * 0.5) + 0.1 * -1.0, v = 0.999 * (0.001 * 0.25) + 0.001 * 1.0;
  const double expect = 0.9 - 0.1 / (1 - 0.81) * m / (std::sqrt(v) / std::sqrt(1 - 0.999 * 0.999) + 1e-8);
  EXPECT_NEAR(a.values()[0], expect, 1e-6);
  EXPECT_EQ(opt.steps(), 2);
}

TEST(Sgd, MomentumAccumulatesVelocityAsInTorch) {
  OptimizerConfig c;
  c.kind = OptimizerKind::Sgd;
  c.lr = 0.1f;
  c.momentum = 0.9f;
  Optimizer opt(c, 1);
  ParamArena a = one_param(1.f, 2.f);
  opt.step(a);  // buf = 2, p = 1 - 0.2
  EXPECT_FLOAT_EQ(a.values()[0], 0.8f);
  opt.step(a);  // buf = 0.9 * 2 + 2 = 3.8, p = 0.8 - 0.38
  EXPECT_FLOAT_EQ(a.values()[0], 0.42f);
}

TEST(Optimizer, ClipNormScalesTheGlobalGradientNorm) {
  OptimizerConfig c;
  c.kind = OptimizerKind::Sgd;
  c.lr = 1.f;
  c.momentum = 0.f;
  c.clip_norm = 1.f;
  ParamArena a;
  a.add("w/weight", Shape{1, 1, 1, 2}, true);
  a.finalize();
  a.grads()[0] = 3;
  a.grads()[1] = 4;  // norm 5 -> scaled to 1
  Optimizer opt(c, a.size());
  opt.step(a);
  EXPECT_NEAR(a.values()[0], -0.6f, 1e-6);
  EXPECT_NEAR(a.values()[1], -0.8f, 1e-6);
}

TEST(Optimizer, UnknownKindAndBadLearningRateAreErrors) {
  EXPECT_EQ(optimizer_kind_from_string("rmsprop"), std::nullopt);
  OptimizerConfig c;
  c.kind = static_cast<OptimizerKind>(kOptimizerKinds);  // outside the enum
  EXPECT_THROW(Optimizer(c, 1), Error);
  c.kind = OptimizerKind::Adam;
  c.lr = std::nanf("");
  EXPECT_THROW(Optimizer(c, 1), Error);
}

// The names are what checkpoints store: renaming one would orphan every saved checkpoint.
TEST(Optimizer, KindNamesRoundTripAsCheckpointsStoreThem) {
  EXPECT_EQ(to_string(OptimizerKind::Adam), "adam");
  EXPECT_EQ(to_string(OptimizerKind::Sgd), "sgd");
  for (int k = 0; k < kOptimizerKinds; ++k)
    EXPECT_EQ(optimizer_kind_from_string(kOptimizerKindNames[k]), static_cast<OptimizerKind>(k));
}

}  // namespace
}  // namespace lidarsim::nn
