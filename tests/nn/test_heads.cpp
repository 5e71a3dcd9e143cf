// The heads' losses (nn/loss.h masked_bce_logits, masked_nll) and their composition
// (nn/heads.h heads_loss) against central differences (eps 1e-6) of the double references in
// reference_losses.h, on [2, 1, 5, 7] with ~60 % of the cells masked in. Error = max |analytic -
// numeric| / max |numeric|, tolerance 1e-4 as for the layers. GradCheckCatchesFaults-style tests
// move one gradient value to a wrong index and require the same check to report > 1e-2.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <algorithm>
#include <functional>
#include <random>
#include <cstdio>
#include <string>

#include "common/error.h"
#include "nn/heads.h"
#include "nn/loss.h"
#include "reference.h"
#include "reference_losses.h"

namespace lidarsim::nn {
namespace {

using namespace reference;

constexpr double kTol = 1e-4;
constexpr double kFaultMin = 1e-2;
const Shape kShape{2, 1, 5, 7};

Tensor random_mask(Shape s, std::uint64_t seed) {
  const Tensor u = random_tensor(s, seed);
  Tensor m(s);
  for (std::size_t i = 0; i < m.numel(); ++i) m.data()[i] = u.data()[i] > -0.2f ? 1.f : 0.f;
  return m;
}

std::vector<double> to_double(const Tensor& t) { return {t.begin(), t.end()}; }

// Masked mean of cell(i) over the double copies, with the op's denominator convention.
double masked_mean(const Tensor& mask, long denominator, const std::function<double(std::size_t)>& cell) {
  double s = 0, valid = 0;
  for (std::size_t i = 0; i < mask.numel(); ++i)
    if (mask.data()[i] != 0.f) s += mask.data()[i] * cell(i), ++valid;
  return s / (denominator > 0 ? double(denominator) : std::max(valid, 1.0));
}

// Swaps the gradient's largest value with its neighbour: what a wrong index in a backward does.
Tensor misplaced(const Tensor& g) {
  Tensor bad = g;
  std::size_t top = 0;
  for (std::size_t i = 0; i + 1 < bad.numel(); ++i)
    if (std::abs(bad.data()[i]) > std::abs(bad.data()[top])) top = i;
  std::swap(bad.data()[top], bad.data()[top + 1]);
  return bad;
}

struct BceCase {
  Tensor z, y, mask;
  long denominator = 0;
};

BceCase bce_case(long denominator = 0) {
  BceCase c{random_tensor(kShape, 1, 6.f), random_tensor(kShape, 2), random_mask(kShape, 3), denominator};
  // Targets: mostly 0 / 1 as a return mask is, some fractional (a soft label).
  for (std::size_t i = 0; i < c.y.numel(); ++i) {
    const float u = c.y.data()[i];
    c.y.data()[i] = i % 5 == 0 ? 0.5f * (u + 1) : u > 0 ? 1.f : 0.f;
  }
  return c;
}

double bce_grad_error(const BceCase& c, const Tensor& g) {
  std::vector<double> z = to_double(c.z);
  auto f = [&] { return masked_mean(c.mask, c.denominator, [&](std::size_t i) { return bce_cell(z[i], c.y.data()[i]); }); };
  return max_rel_error(g.data(), numeric_gradient(z, f));
}

TEST(MaskedBceLogitsGradCheck, LossAndGradientMatchTheReferenceAndFiniteDifferences) {
  for (long denominator : {0L, 50L}) {
    const BceCase c = bce_case(denominator);
    Tensor g;
    const LossParts parts = masked_bce_logits(c.z, c.y, c.mask, &g, denominator);
    const double want = masked_mean(c.mask, denominator, [&](std::size_t i) { return bce_cell(c.z.data()[i], c.y.data()[i]); });
    const double err = bce_grad_error(c, g);
    std::printf("[ measured ] bce denominator %ld: loss %.6f (reference %.6f), gradient error %.1e\n", denominator,
                parts.data, want, err);
    EXPECT_NEAR(parts.data, want, 1e-6 * std::abs(want));
    EXPECT_LT(err, kTol);
    for (std::size_t i = 0; i < g.numel(); ++i) {
      if (c.mask.data()[i] == 0.f) {
        EXPECT_EQ(g.data()[i], 0.f) << i;
      }
    }
  }
}

TEST(MaskedBceLogits, StaysFiniteAndExactForHugeLogits) {
  const Shape s6{1, 1, 1, 6};
  Tensor z(s6), y(s6), m(s6), g;
  const float zs[] = {1000.f, -1000.f, 80.f, -80.f, 1000.f, -1000.f};
  const float ys[] = {1.f, 0.f, 1.f, 0.f, 0.f, 1.f};
  for (int i = 0; i < 6; ++i) z.data()[i] = zs[i], y.data()[i] = ys[i], m.data()[i] = 1.f;
  const LossParts parts = masked_bce_logits(z, y, m, &g);
  // The first four are right with certainty (loss ~0), the last two wrong by 1000 each.
  EXPECT_NEAR(parts.data, 2000.0 / 6, 1e-9);
  const float want_g[] = {0.f, 0.f, 0.f, 0.f, 1.f / 6, -1.f / 6};
  for (int i = 0; i < 6; ++i) EXPECT_NEAR(g.data()[i], want_g[i], 1e-7) << i;
}

TEST(MaskedBceLogits, TargetOutsideZeroToOneAndNonFiniteLogitAreErrorsNamingTheField) {
  BceCase c = bce_case();
  std::size_t first = 0;
  while (c.mask.data()[first] == 0.f) ++first;
  c.y.data()[first] = 1.5f;
  try {
    masked_bce_logits(c.z, c.y, c.mask, nullptr);
    FAIL() << "a target of 1.5 was accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("target: expected 0..1 at flat index " + std::to_string(first)), std::string::npos)
        << e.what();
  }
  c = bce_case();
  c.z.data()[first] = NAN;
  EXPECT_THROW(masked_bce_logits(c.z, c.y, c.mask, nullptr), Error);
  c.z.data()[first] = 0.f;
  c.mask.data()[first] = 0.f;
  c.y.data()[first] = 7.f;  // masked out: not looked at
  EXPECT_NO_THROW(masked_bce_logits(c.z, c.y, c.mask, nullptr));
}

struct NllCase {
  Tensor mu, s, y, mask;
};

NllCase nll_case() {
  NllCase c{random_tensor(kShape, 11, 0.5f), random_tensor(kShape, 12, 2.f), random_tensor(kShape, 13, 0.5f),
            random_mask(kShape, 14)};
  // A few log-scales beyond the clamp on both sides (no gradient there), far from its edges.
  c.s.data()[3] = -9.f;
  c.s.data()[8] = 4.5f;
  c.s.data()[20] = -8.f;
  c.mask.data()[3] = c.mask.data()[8] = c.mask.data()[20] = 1.f;
  // Targets near the mean where the scale is tiny, so no single cell dominates the check's scale.
  c.y.data()[3] = c.mu.data()[3] + 1e-3f;
  c.y.data()[20] = c.mu.data()[20] - 5e-4f;
  return c;
}

struct NllErrors {
  double loss = 0, d_mean = 0, d_log_scale = 0;
};

NllErrors check_nll(Spread family, long denominator, bool fault = false) {
  const NllCase c = nll_case();
  const LogScaleClamp clamp{};
  Tensor gm, gs;
  const LossParts parts = masked_nll(family, c.mu, c.s, c.y, c.mask, &gm, &gs, denominator, clamp);
  std::vector<double> mu = to_double(c.mu), s = to_double(c.s);
  auto f = [&] {
    return masked_mean(c.mask, denominator, [&](std::size_t i) {
      return family == Spread::gaussian ? gaussian_nll_cell(mu[i], s[i], c.y.data()[i], clamp.min, clamp.max)
                                        : laplace_nll_cell(mu[i], s[i], c.y.data()[i], clamp.min, clamp.max);
    });
  };
  NllErrors e;
  e.loss = std::abs(parts.data - f()) / std::abs(f());
  e.d_mean = max_rel_error(fault ? misplaced(gm).data() : gm.data(), numeric_gradient(mu, f));
  e.d_log_scale = max_rel_error(gs.data(), numeric_gradient(s, f));
  std::printf("[ measured ] %s nll denominator %ld: loss rel. error %.1e, d_mean %.1e, d_log_scale %.1e\n",
              family == Spread::gaussian ? "gaussian" : "laplace", denominator, e.loss, e.d_mean, e.d_log_scale);
  // Clamped cells: no gradient to the log-scale.
  EXPECT_EQ(gs.data()[3], 0.f);
  EXPECT_EQ(gs.data()[8], 0.f);
  return e;
}

TEST(MaskedNllGradCheck, GaussianMeanAndLogScaleMatchFiniteDifferencesWithTheClamp) {
  for (long denominator : {0L, 50L}) {
    const NllErrors e = check_nll(Spread::gaussian, denominator);
    EXPECT_LT(e.loss, 1e-6);
    EXPECT_LT(e.d_mean, kTol);
    EXPECT_LT(e.d_log_scale, kTol);
  }
}

TEST(MaskedNllGradCheck, LaplaceMeanAndLogScaleMatchFiniteDifferencesWithTheClamp) {
  for (long denominator : {0L, 50L}) {
    const NllErrors e = check_nll(Spread::laplace, denominator);
    EXPECT_LT(e.loss, 1e-6);
    EXPECT_LT(e.d_mean, kTol);
    EXPECT_LT(e.d_log_scale, kTol);
  }
}

TEST(MaskedNll, NullMeanGradientLeavesTheMeanAloneAndBadClampIsAnError) {
  const NllCase c = nll_case();
  Tensor gs1, gs2, gm;
  const LossParts a = masked_nll(Spread::gaussian, c.mu, c.s, c.y, c.mask, nullptr, &gs1);
  const LossParts b = masked_nll(Spread::gaussian, c.mu, c.s, c.y, c.mask, &gm, &gs2);
  EXPECT_EQ(a.data, b.data);
  EXPECT_EQ(std::memcmp(gs1.data(), gs2.data(), gs1.numel() * sizeof(float)), 0);
  EXPECT_THROW(masked_nll(Spread::laplace, c.mu, c.s, c.y, c.mask, nullptr, nullptr, 0, {3.f, -3.f}), Error);
  Tensor wrong(Shape{2, 1, 5, 6});
  EXPECT_THROW(masked_nll(Spread::laplace, c.mu, wrong, c.y, c.mask, nullptr, nullptr), Error);
}

TEST(GradCheckCatchesFaults, WrongIndexInTheBceGradient) {
  const BceCase c = bce_case();
  Tensor g;
  masked_bce_logits(c.z, c.y, c.mask, &g);
  EXPECT_GT(bce_grad_error(c, misplaced(g)), kFaultMin);
}

TEST(GradCheckCatchesFaults, WrongIndexInTheNllMeanGradient) {
  EXPECT_GT(check_nll(Spread::gaussian, 0, true).d_mean, kFaultMin);
  EXPECT_GT(check_nll(Spread::laplace, 0, true).d_mean, kFaultMin);
}

// heads_loss over a [2, 3, 5, 7] prediction (mean, return, spread): every channel's gradient,
// weights included, against the numeric gradient of the weighted sum; with and without the
// spread's gradient reaching the mean.
double check_heads_loss(HeadKind spread, bool spread_trains_mean) {
  const std::vector<HeadKind> heads{HeadKind::mean, HeadKind::return_logit, spread};
  const Shape ps{2, 3, 5, 7};
  Tensor pred = random_tensor(ps, 21, 1.5f);
  const Tensor intensity = random_tensor(kShape, 22, 0.5f), returned = bce_case().y;
  const Tensor m_int = random_mask(kShape, 23), m_ret = random_mask(kShape, 24);
  const std::vector<HeadTarget> targets{{&intensity, &m_int, 1.f, 0}, {&returned, &m_ret, 0.5f, 60}, {&intensity, &m_int, 0.25f, 0}};
  HeadsLossConfig cfg;
  cfg.spread_trains_mean = spread_trains_mean;
  Tensor d;
  const HeadsLoss loss = heads_loss(heads, pred, targets, &d, cfg);
  EXPECT_EQ(loss.per_head.size(), 3u);
  std::vector<double> p = to_double(pred);
  const std::size_t plane = kShape.plane();
  auto at = [&](std::size_t cell, int c) { return p[(cell / plane * 3 + c) * plane + cell % plane]; };
  auto f = [&] {
    const double mse = masked_mean(m_int, 0, [&](std::size_t i) {
      const double r = at(i, 0) - intensity.data()[i];
      return r * r;
    });
    const double bce = masked_mean(m_ret, 60, [&](std::size_t i) { return bce_cell(at(i, 1), returned.data()[i]); });
    const double nll = masked_mean(m_int, 0, [&](std::size_t i) {
      const double mu = at(i, 0), s = at(i, 2), y = intensity.data()[i];
      return spread == HeadKind::log_scale_gaussian ? gaussian_nll_cell(mu, s, y, -7, 3) : laplace_nll_cell(mu, s, y, -7, 3);
    });
    return mse + 0.5 * bce + 0.25 * nll;
  };
  EXPECT_NEAR(loss.total, f(), 1e-6 * std::abs(f()));
  std::vector<double> numeric = numeric_gradient(p, f);
  if (!spread_trains_mean) {  // the mean channel then sees the MSE only: take the NLL's part out
    std::vector<double> mu(plane * 2);
    for (int n = 0; n < 2; ++n)
      for (std::size_t i = 0; i < plane; ++i) mu[n * plane + i] = p[(n * 3) * plane + i];
    auto mse_only = [&] {
      return masked_mean(m_int, 0, [&](std::size_t i) {
        const double r = mu[i] - intensity.data()[i];
        return r * r;
      });
    };
    const std::vector<double> g0 = numeric_gradient(mu, mse_only);
    for (int n = 0; n < 2; ++n)
      for (std::size_t i = 0; i < plane; ++i) numeric[(n * 3) * plane + i] = g0[n * plane + i];
  }
  const double err = max_rel_error(d.data(), numeric);
  std::printf("[ measured ] heads_loss mean,return_logit,%s (spread trains mean: %d): gradient error %.1e\n",
              head_name(spread), spread_trains_mean, err);
  return err;
}

TEST(HeadsLossGradCheck, EveryChannelWithWeightsAndDenominatorsMatchesFiniteDifferences) {
  for (HeadKind spread : {HeadKind::log_scale_gaussian, HeadKind::log_scale_laplace})
    for (bool trains_mean : {false, true}) EXPECT_LT(check_heads_loss(spread, trains_mean), kTol);
}

TEST(Heads, NamesRoundTripAndTheRulesNameTheProblem) {
  const std::vector<HeadKind> all{HeadKind::mean, HeadKind::return_logit, HeadKind::log_scale_laplace};
  EXPECT_EQ(heads_text(all), "mean,return_logit,log_scale_laplace");
  EXPECT_EQ(parse_heads("mean,return_logit,log_scale_laplace", "x"), all);
  EXPECT_NO_THROW(check_heads(all, 3, "x"));
  EXPECT_NO_THROW(check_heads({}, 5, "x"));
  auto message = [](const std::function<void()>& f) {
    try {
      f();
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(message([] { parse_heads("mean,spread", "cfg"); }).find("cfg: unknown head \"spread\""), std::string::npos);
  EXPECT_NE(message([&] { check_heads(all, 2, "cfg"); }).find("one head per output channel"), std::string::npos);
  EXPECT_NE(message([] { check_heads({HeadKind::return_logit, HeadKind::mean}, 2, "cfg"); }).find("channel 0 must be the mean"),
            std::string::npos);
  EXPECT_NE(message([] { check_heads({HeadKind::mean, HeadKind::return_logit, HeadKind::return_logit}, 3, "cfg"); })
                .find("more than once"),
            std::string::npos);
  EXPECT_NE(message([] {
              check_heads({HeadKind::mean, HeadKind::log_scale_gaussian, HeadKind::log_scale_laplace}, 3, "cfg");
            }).find("at most one spread head"),
            std::string::npos);
}

TEST(Heads, OutputTransformGivesProbabilitiesAndScalesAndLeavesTheMean) {
  Tensor y(Shape{1, 3, 1, 4});
  const float v[] = {0.3f, -2.f, 0.f, 1.f, 0.f, 100.f, -100.f, 2.f, -1.f, -20.f, 20.f, 0.f};
  std::copy(v, v + 12, y.data());
  heads_output_transform(y, {HeadKind::mean, HeadKind::return_logit, HeadKind::log_scale_gaussian});
  for (int i = 0; i < 4; ++i) EXPECT_EQ(y.data()[i], v[i]);
  EXPECT_FLOAT_EQ(y.data()[4], 0.5f);
  EXPECT_FLOAT_EQ(y.data()[5], 1.f);
  EXPECT_GE(y.data()[6], 0.f);
  EXPECT_LT(y.data()[6], 1e-40f);
  EXPECT_FLOAT_EQ(y.data()[7], 1.f / (1.f + std::exp(-2.f)));
  EXPECT_FLOAT_EQ(y.data()[8], std::exp(-1.f));
  EXPECT_FLOAT_EQ(y.data()[9], std::exp(-7.f));  // clamped
  EXPECT_FLOAT_EQ(y.data()[10], std::exp(3.f));
  EXPECT_FLOAT_EQ(y.data()[11], 1.f);
  EXPECT_THROW(heads_output_transform(y, {HeadKind::mean, HeadKind::return_logit}), Error);
}

// The zero head reuses the return head's op (masked BCE on logits, checked above and against
// PyTorch) on the indicator target <= 0: its loss and gradient are that op's, bit for bit; its
// output is a probability; it needs a spread (a draw that is not 0 comes from it).
TEST(Heads, ZeroHeadIsTheBceOfTheZeroIndicatorAndNeedsASpread) {
  const std::vector<HeadKind> heads{HeadKind::mean, HeadKind::log_scale_laplace, HeadKind::zero_logit};
  EXPECT_EQ(parse_heads("mean,log_scale_laplace,zero_logit", "x"), heads);
  EXPECT_EQ(head_channel(heads, HeadKind::zero_logit), 2);
  EXPECT_EQ(head_channel(heads, HeadKind::return_logit), -1);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-2.f, 2.f);
  Tensor pred(Shape{2, 3, 3, 5}), y(Shape{2, 1, 3, 5}), m(Shape{2, 1, 3, 5});
  for (float& v : pred) v = u(rng);
  for (std::size_t i = 0; i < y.numel(); ++i) {
    y.data()[i] = i % 3 == 0 ? 0.f : 0.5f + 0.2f * u(rng);
    m.data()[i] = i % 5 == 0 ? 0.f : 1.f;
  }
  Tensor zero, d_pred, z(Shape{2, 1, 3, 5}), g;
  zero_indicator(zero, y);
  for (std::size_t i = 0; i < y.numel(); ++i) EXPECT_EQ(zero.data()[i], y.data()[i] <= 0 ? 1.f : 0.f);
  const HeadsLoss loss = heads_loss(heads, pred, {{&y, &m}, {&y, &m}, {&zero, &m}}, &d_pred);
  for (int n = 0; n < 2; ++n) std::copy_n(pred.channel(n, 2), 15, z.image(n));
  const LossParts bce = masked_bce_logits(z, zero, m, &g);
  EXPECT_EQ(loss.per_head[2].data, bce.data);
  for (int n = 0; n < 2; ++n)
    for (int i = 0; i < 15; ++i) EXPECT_EQ(d_pred.channel(n, 2)[i], g.image(n)[i]);
  Tensor out = pred;
  heads_output_transform(out, heads);
  EXPECT_FLOAT_EQ(out.channel(0, 2)[0], static_cast<float>(logit_probability(pred.channel(0, 2)[0])));
  EXPECT_THROW(check_heads({HeadKind::mean, HeadKind::zero_logit}, 2, "cfg"), Error);
  EXPECT_NEAR(nonzero_center(0.28, 0.3), 0.4, 1e-12);
  EXPECT_NEAR(nonzero_center(0.28, 0.99), 2.8, 1e-12);  // p0 capped at 0.9
}

}  // namespace
}  // namespace lidarsim::nn
