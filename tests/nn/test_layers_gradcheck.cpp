// Finite-difference gradient checks for every layer op: our float backward against central
// differences (eps 1e-6) of an independent double-precision reference forward. The scalar is
// L = sum(out * R) with a fixed random R, so d_out = R. Error = max |analytic - numeric| /
// max |numeric| over all entries; tolerance kTol = 1e-4 (measured errors are ~1e-7..1e-6).
// The Fault* tests turn on a test-only hook that puts one gradient value at a wrong index and
// assert the same check then reports an error above kFaultMin: the check can fail.
#include <gtest/gtest.h>

#include <cstdio>

#include "common/error.h"
#include "conv_path.h"
#include "nn/layers.h"
#include "nn/winograd.h"
#include "reference.h"

namespace lidarsim::nn {
namespace {

using namespace reference;

constexpr double kLayerTol = 1e-4;
constexpr double kLayerFaultMin = 1e-2;  // 100x the tolerance

struct FaultGuard {
  explicit FaultGuard(testhook::Fault f) { testhook::fault = f; }
  ~FaultGuard() { testhook::fault = testhook::Fault::none; }
};

std::vector<double> as_doubles(const std::vector<float>& v) { return {v.begin(), v.end()}; }
std::vector<double> as_doubles(const Tensor& t) { return {t.begin(), t.end()}; }

struct LayerErrors {
  double forward = 0, d_in = 0, d_weight = 0, d_bias = 0;
  double worst_backward() const { return std::max({d_in, d_weight, d_bias}); }
};

struct ConvCase {
  int n, ci, h, w, co, k, pad;
  bool relu;
};

LayerErrors check_conv2d(const ConvCase& c) {
  const Tensor x = random_tensor(Shape{c.n, c.ci, c.h, c.w}, 1);
  const std::vector<float> w = random_vector(std::size_t(c.co) * c.ci * c.k * c.k, 2, 0.5f);
  const std::vector<float> b = random_vector(std::size_t(c.co), 3, 0.3f);
  Tensor y;
  conv2d_forward(y, x, w.data(), b.data(), c.co, c.k, c.pad, c.relu);
  const Tensor r = random_tensor(y.shape(), 4);
  const std::vector<double> rd = as_doubles(r);
  Tensor d_in;
  std::vector<float> dw(w.size(), 0.f), db(b.size(), 0.f);
  conv2d_backward(&d_in, dw.data(), db.data(), r, y, x, w.data(), c.k, c.pad, c.relu);

  DT xd = from(x);
  std::vector<double> wd = as_doubles(w), bd = as_doubles(b);
  auto f = [&] { return dot(conv2d(xd, wd, bd, c.co, c.k, c.pad, c.relu), rd); };
  LayerErrors e;
  e.forward = max_rel_error(y.data(), conv2d(xd, wd, bd, c.co, c.k, c.pad, c.relu).v);
  e.d_in = max_rel_error(d_in.data(), numeric_gradient(xd.v, f));
  e.d_weight = max_rel_error(dw.data(), numeric_gradient(wd, f));
  e.d_bias = max_rel_error(db.data(), numeric_gradient(bd, f));
  std::printf("[ measured ] conv2d k %d pad %d: forward %.1e, d_in %.1e, d_weight %.1e, d_bias %.1e\n", c.k, c.pad,
              e.forward, e.d_in, e.d_weight, e.d_bias);
  return e;
}

TEST(Conv2dGradCheck, EveryKernelPaddingAndReluMatchesFiniteDifferences) {
  conv_paths::Conv3x3PathGuard direct(detail::Conv3x3Path::direct);
  const ConvCase cases[] = {
      {2, 3, 7, 9, 4, 3, 1, true},   // the UNet's conv, odd sizes
      {2, 3, 5, 11, 5, 3, 1, false},
      {2, 4, 7, 9, 3, 1, 0, false},  // 1x1 head
      {2, 2, 6, 7, 3, 5, 2, true},   // 5x5
      {2, 2, 7, 9, 3, 3, 0, false},  // valid conv, shrinks the map
      {1, 3, 9, 5, 2, 3, 2, false},  // more padding than k/2: grows the map
  };
  for (const ConvCase& c : cases) {
    SCOPED_TRACE("k " + std::to_string(c.k) + " pad " + std::to_string(c.pad) + " relu " + std::to_string(c.relu) +
                 " input " + std::to_string(c.h) + "x" + std::to_string(c.w));
    const LayerErrors e = check_conv2d(c);
    EXPECT_LT(e.forward, 1e-5);
    EXPECT_LT(e.d_in, kLayerTol);
    EXPECT_LT(e.d_weight, kLayerTol);
    EXPECT_LT(e.d_bias, kLayerTol);
  }
}

LayerErrors check_conv_transpose(int out_h, int out_w) {
  const int n = 2, ci = 3, h = 3, w = 4, co = 2;
  const Tensor x = random_tensor(Shape{n, ci, h, w}, 11);
  const std::vector<float> wt = random_vector(std::size_t(ci) * co * 4, 12, 0.5f);
  const std::vector<float> b = random_vector(std::size_t(co), 13, 0.3f);
  Tensor y;
  conv_transpose2x2_forward(y, x, wt.data(), b.data(), co, out_h, out_w);
  const Tensor r = random_tensor(y.shape(), 14);
  Tensor d_in;
  std::vector<float> dw(wt.size(), 0.f), db(b.size(), 0.f);
  conv_transpose2x2_backward(d_in, dw.data(), db.data(), r, x, wt.data());

  DT xd = from(x);
  std::vector<double> wd = as_doubles(wt), bd = as_doubles(b);
  const std::vector<double> rd = as_doubles(r);
  auto f = [&] { return dot(conv_transpose2x2(xd, wd, bd, co, out_h, out_w), rd); };
  LayerErrors e;
  e.forward = max_rel_error(y.data(), conv_transpose2x2(xd, wd, bd, co, out_h, out_w).v);
  e.d_in = max_rel_error(d_in.data(), numeric_gradient(xd.v, f));
  e.d_weight = max_rel_error(dw.data(), numeric_gradient(wd, f));
  e.d_bias = max_rel_error(db.data(), numeric_gradient(bd, f));
  return e;
}

// The same checks with the 3x3 convolutions on Winograd F(4x4, 3x3) (forward and input
// gradient; the weight gradient stays direct): odd sizes, partial tiles, with and without ReLU.
TEST(Conv2dGradCheck, WinogradPathMatchesFiniteDifferences) {
  if (!detail::winograd_available()) GTEST_SKIP() << "built without AVX2 kernels (LIDARSIM_ARCH below x86-64-v3): no Winograd path";
  conv_paths::Conv3x3PathGuard winograd(detail::Conv3x3Path::winograd);
  const ConvCase cases[] = {{2, 3, 7, 9, 4, 3, 1, true}, {2, 3, 5, 11, 5, 3, 1, false}, {1, 9, 6, 13, 10, 3, 1, true}};
  for (const ConvCase& c : cases) {
    SCOPED_TRACE("relu " + std::to_string(c.relu) + " input " + std::to_string(c.h) + "x" + std::to_string(c.w));
    const LayerErrors e = check_conv2d(c);
    EXPECT_LT(e.forward, 1e-5);
    EXPECT_LT(e.d_in, kLayerTol);
    EXPECT_LT(e.d_weight, kLayerTol);
    EXPECT_LT(e.d_bias, kLayerTol);
  }
}

TEST(ConvTransposeGradCheck, ExactAndZeroPaddedOutputsMatchFiniteDifferences) {
  for (auto [oh, ow] : {std::pair{6, 8}, std::pair{7, 9}}) {
    SCOPED_TRACE("output " + std::to_string(oh) + "x" + std::to_string(ow));
    const LayerErrors e = check_conv_transpose(oh, ow);
    EXPECT_LT(e.forward, 1e-5);
    EXPECT_LT(e.worst_backward(), kLayerTol);
  }
}

TEST(ConvTranspose, PaddedRowsAndColumnsAreZeroWithoutBias) {
  const Tensor x = random_tensor(Shape{1, 2, 2, 3}, 5);
  const std::vector<float> w = random_vector(2 * 3 * 4, 6), b{1.f, 2.f, 3.f};
  Tensor y;
  conv_transpose2x2_forward(y, x, w.data(), b.data(), 3, 5, 7);
  for (int c = 0; c < 3; ++c) {
    for (int xx = 0; xx < 7; ++xx) EXPECT_EQ(y.at(0, c, 4, xx), 0.f);
    for (int yy = 0; yy < 5; ++yy) EXPECT_EQ(y.at(0, c, yy, 6), 0.f);
  }
}

// The register-blocked forward kernel (nn/conv_transpose2x2.h) works on 32 input columns and two
// output channels at a time: rows that end inside a block, an odd channel out and padded outputs
// must all match the double reference, on the serial and the parallel path.
TEST(ConvTranspose, BlockedKernelMatchesTheReferenceAtEveryEdge) {
  struct Case {
    int n, ci, h, w, co, out_h, out_w;
  };
  for (const Case& c : {Case{1, 5, 3, 37, 3, 6, 74}, Case{2, 7, 4, 16, 5, 9, 35}, Case{1, 3, 2, 1, 1, 4, 2},
                        Case{2, 64, 16, 96, 32, 32, 192}}) {
    SCOPED_TRACE("in " + std::to_string(c.ci) + "x" + std::to_string(c.h) + "x" + std::to_string(c.w) + " co " +
                 std::to_string(c.co));
    const Tensor x = random_tensor(Shape{c.n, c.ci, c.h, c.w}, 31);
    const std::vector<float> wt = random_vector(std::size_t(c.ci) * c.co * 4, 32, 0.5f);
    const std::vector<float> b = random_vector(std::size_t(c.co), 33, 0.3f);
    Tensor y;
    conv_transpose2x2_forward(y, x, wt.data(), b.data(), c.co, c.out_h, c.out_w);
    const DT ref = conv_transpose2x2(from(x), as_doubles(wt), as_doubles(b), c.co, c.out_h, c.out_w);
    EXPECT_LT(max_rel_error(y.data(), ref.v), 1e-5);
  }
}

double check_max_pool(int h, int w) {
  const Tensor x = random_tensor(Shape{2, 3, h, w}, 21);
  Tensor y;
  std::vector<std::int32_t> am;
  max_pool2x2_forward(y, am, x);
  const Tensor r = random_tensor(y.shape(), 22);
  Tensor d_in;
  max_pool2x2_backward(d_in, r, am, x.shape());
  DT xd = from(x);
  const std::vector<double> rd = as_doubles(r);
  EXPECT_LT(max_rel_error(y.data(), max_pool2x2(xd).v), 1e-7);
  return max_rel_error(d_in.data(), numeric_gradient(xd.v, [&] { return dot(max_pool2x2(xd), rd); }));
}

TEST(MaxPoolGradCheck, EvenAndOddInputsMatchFiniteDifferences) {
  EXPECT_LT(check_max_pool(6, 8), kLayerTol);
  EXPECT_LT(check_max_pool(7, 9), kLayerTol);  // the last row/column is dropped (floor)
}

TEST(MaxPool, ArgmaxIsTheFlatIndexOfTheMaximumInTheInputPlane) {
  Tensor x(1, 1, 2, 4);
  const float v[] = {1, 5, 2, 0, 3, 4, 9, 1};
  std::copy(v, v + 8, x.begin());
  Tensor y;
  std::vector<std::int32_t> am;
  max_pool2x2_forward(y, am, x);
  EXPECT_EQ(y.at(0, 0, 0, 0), 5.f);
  EXPECT_EQ(y.at(0, 0, 0, 1), 9.f);
  EXPECT_EQ(am, (std::vector<std::int32_t>{1, 6}));
}

double check_relu() {
  const Tensor x = random_tensor(Shape{2, 3, 5, 7}, 31);
  Tensor y, d_in;
  relu_forward(y, x);
  const Tensor r = random_tensor(y.shape(), 32);
  relu_backward(d_in, r, y);
  DT xd = from(x);
  const std::vector<double> rd = as_doubles(r);
  return max_rel_error(d_in.data(), numeric_gradient(xd.v, [&] { return dot(relu(xd), rd); }));
}

TEST(ReluGradCheck, MatchesFiniteDifferences) { EXPECT_LT(check_relu(), kLayerTol); }

double check_concat() {
  const Tensor a = random_tensor(Shape{2, 2, 3, 5}, 41), b = random_tensor(Shape{2, 3, 3, 5}, 42);
  Tensor y;
  concat_forward(y, a, b);
  const Tensor r = random_tensor(y.shape(), 43);
  Tensor da(a.shape()), db;
  concat_backward(da, db, r);
  DT ad = from(a), bd = from(b);
  const std::vector<double> rd = as_doubles(r);
  auto f = [&] { return dot(concat(ad, bd), rd); };
  EXPECT_LT(max_rel_error(y.data(), concat(ad, bd).v), 1e-7);
  return std::max(max_rel_error(da.data(), numeric_gradient(ad.v, f)),
                  max_rel_error(db.data(), numeric_gradient(bd.v, f)));
}

TEST(ConcatGradCheck, MatchesFiniteDifferences) { EXPECT_LT(check_concat(), kLayerTol); }

// Reference: y = gain[c, h] * x + offset[c, h], written out in double.
DT row_affine(const DT& x, const std::vector<double>& gain, const std::vector<double>& offset) {
  DT y = x;
  for (int n = 0; n < x.s.n; ++n)
    for (int c = 0; c < x.s.c; ++c)
      for (int h = 0; h < x.s.h; ++h)
        for (int w = 0; w < x.s.w; ++w) {
          const std::size_t k = std::size_t(c) * x.s.h + h;
          y.at(n, c, h, w) = gain[k] * x.at(n, c, h, w) + offset[k];
        }
  return y;
}

LayerErrors check_row_affine() {
  const Tensor x = random_tensor(Shape{2, 3, 5, 7}, 51);
  std::vector<float> gain = random_vector(15, 52, 0.5f), offset = random_vector(15, 53, 0.3f);
  for (float& g : gain) g += 1.f;
  Tensor y, d_in;
  row_affine_forward(y, x, gain.data(), offset.data());
  const Tensor r = random_tensor(y.shape(), 54);
  std::vector<float> dg(gain.size(), 0.f), db(offset.size(), 0.f);
  row_affine_backward(d_in, dg.data(), db.data(), r, x, gain.data());
  DT xd = from(x);
  std::vector<double> gd = as_doubles(gain), od = as_doubles(offset);
  const std::vector<double> rd = as_doubles(r);
  auto f = [&] { return dot(row_affine(xd, gd, od), rd); };
  LayerErrors e;
  e.forward = max_rel_error(y.data(), row_affine(xd, gd, od).v);
  e.d_in = max_rel_error(d_in.data(), numeric_gradient(xd.v, f));
  e.d_weight = max_rel_error(dg.data(), numeric_gradient(gd, f));
  e.d_bias = max_rel_error(db.data(), numeric_gradient(od, f));
  std::printf("[ measured ] row affine: forward %.1e, d_in %.1e, d_gain %.1e, d_offset %.1e\n", e.forward, e.d_in,
              e.d_weight, e.d_bias);
  return e;
}

TEST(RowAffineGradCheck, InputGainAndOffsetGradientsMatchFiniteDifferences) {
  const LayerErrors e = check_row_affine();
  EXPECT_LT(e.forward, 1e-6);
  EXPECT_LT(e.worst_backward(), kLayerTol);
}

// A lookup-base input: 3 one-hot class channels (some cells in none), a range channel with
// empty cells (0) and values beyond the last bin, one more unrelated channel.
struct LookupCase {
  Tensor x;
  LookupBaseConfig c{3, 1, 0, 4, 0.25f, 5};
};
LookupCase lookup_case() {
  LookupCase k;
  k.x = random_tensor(Shape{2, 5, 5, 7}, 61);
  const Tensor u = random_tensor(Shape{2, 1, 5, 7}, 62);
  for (int n = 0; n < 2; ++n)
    for (int i = 0; i < 35; ++i) {
      const float v = u.data()[n * 35 + i];
      float& range = k.x.channel(n, 0)[i];
      range = v < -0.8f ? 0.f : 1.3f * std::abs(v) + 0.01f;  // 0 = no return; up to 1.3 (> 4 bins)
      const int g = static_cast<int>((v + 1.f) * 2.f);       // 0..3, 3 = no group
      for (int j = 0; j < 3; ++j) k.x.channel(n, 1 + j)[i] = j == g ? 1.f : 0.f;
    }
  return k;
}

LayerErrors check_lookup_base() {
  const LookupCase k = lookup_case();
  const std::vector<float> table = random_vector(16, 63), beam = random_vector(5, 64, 0.3f);
  Tensor y;
  lookup_base_forward(y, k.x, k.c, table.data(), beam.data());
  const Tensor r = random_tensor(y.shape(), 65);
  std::vector<float> dt(table.size(), 0.f), db(beam.size(), 0.f);
  lookup_base_backward(dt.data(), db.data(), r, k.x, k.c);
  const DT xd = from(k.x);
  std::vector<double> td = as_doubles(table), bd = as_doubles(beam);
  const std::vector<double> rd = as_doubles(r);
  auto f = [&] { return dot(lookup_base(xd, k.c, td, bd), rd); };
  LayerErrors e;
  e.forward = max_rel_error(y.data(), lookup_base(xd, k.c, td, bd).v);
  e.d_weight = max_rel_error(dt.data(), numeric_gradient(td, f));
  e.d_bias = max_rel_error(db.data(), numeric_gradient(bd, f));
  std::printf("[ measured ] lookup base: forward %.1e, d_table %.1e, d_beam %.1e\n", e.forward, e.d_weight, e.d_bias);
  return e;
}

TEST(LookupBaseGradCheck, TableAndBeamGradientsMatchFiniteDifferences) {
  const LayerErrors e = check_lookup_base();
  EXPECT_LT(e.forward, 1e-6);
  EXPECT_LT(e.worst_backward(), kLayerTol);
}

TEST(LookupBase, KeysFollowTheFirstHotClassAndTheRangeBinAndSkipEmptyCells) {
  const LookupCase k = lookup_case();
  std::vector<std::int32_t> keys;
  lookup_base_keys(keys, k.x, k.c);
  int empty = 0, none = 0, last_bin = 0;
  for (std::size_t i = 0; i < keys.size(); ++i) {
    const int n = static_cast<int>(i / 35), j = static_cast<int>(i % 35);
    const float range = k.x.channel(n, 0)[j];
    if (range == 0.f) {
      EXPECT_EQ(keys[i], -1);
      ++empty;
      continue;
    }
    int g = 3;
    for (int c = 2; c >= 0; --c)
      if (k.x.channel(n, 1 + c)[j] == 1.f) g = c;
    const int b = std::min(3, static_cast<int>(range / 0.25f));
    EXPECT_EQ(keys[i], g * 4 + b);
    none += g == 3;
    last_bin += range >= 1.f;
  }
  EXPECT_GT(empty, 0);  // the case covers every branch
  EXPECT_GT(none, 0);
  EXPECT_GT(last_bin, 0);
  LookupBaseConfig wrong = k.c;
  wrong.rows = 4;
  EXPECT_THROW(lookup_base_keys(keys, k.x, wrong), Error);
}

// --- The checks can fail: each fault puts one value at a wrong index. ---

TEST(GradCheckCatchesFaults, WrongIndexInConv2dInputGradient) {
  FaultGuard g(testhook::Fault::conv2d_input);
  EXPECT_GT(check_conv2d({2, 3, 7, 9, 4, 3, 1, false}).d_in, kLayerFaultMin);
}
TEST(GradCheckCatchesFaults, WrongIndexInConv2dWeightGradient) {
  FaultGuard g(testhook::Fault::conv2d_weight);
  EXPECT_GT(check_conv2d({2, 3, 7, 9, 4, 3, 1, false}).d_weight, kLayerFaultMin);
}
TEST(GradCheckCatchesFaults, WrongIndexInConv2dBiasGradient) {
  FaultGuard g(testhook::Fault::conv2d_bias);
  EXPECT_GT(check_conv2d({2, 3, 7, 9, 4, 3, 1, false}).d_bias, kLayerFaultMin);
}
TEST(GradCheckCatchesFaults, WrongIndexInConvTransposeGradients) {
  {
    FaultGuard g(testhook::Fault::conv_transpose_input);
    EXPECT_GT(check_conv_transpose(7, 9).d_in, kLayerFaultMin);
  }
  FaultGuard g(testhook::Fault::conv_transpose_weight);
  EXPECT_GT(check_conv_transpose(7, 9).d_weight, kLayerFaultMin);
}
TEST(GradCheckCatchesFaults, WrongIndexInMaxPoolGradient) {
  FaultGuard g(testhook::Fault::max_pool);
  EXPECT_GT(check_max_pool(6, 8), kLayerFaultMin);
}
TEST(GradCheckCatchesFaults, WrongIndexInReluGradient) {
  FaultGuard g(testhook::Fault::relu);
  EXPECT_GT(check_relu(), kLayerFaultMin);
}
TEST(GradCheckCatchesFaults, WrongIndexInRowAffineGainGradient) {
  FaultGuard g(testhook::Fault::row_affine);
  EXPECT_GT(check_row_affine().d_weight, kLayerFaultMin);
}
TEST(GradCheckCatchesFaults, WrongIndexInLookupBaseBeamGradient) {
  FaultGuard g(testhook::Fault::lookup_base);
  EXPECT_GT(check_lookup_base().d_bias, kLayerFaultMin);
}
TEST(GradCheckCatchesFaults, WrongIndexInConcatGradient) {
  FaultGuard g(testhook::Fault::concat);
  EXPECT_GT(check_concat(), kLayerFaultMin);
}

}  // namespace
}  // namespace lidarsim::nn

namespace lidarsim::nn {
namespace {

// The decoder's conv over [skip, up] without a concat copy equals concat + conv2d, both ways.
TEST(Conv2dCat, MatchesConcatThenConvForwardAndBackward) {
  const Tensor a = reference::random_tensor(Shape{2, 3, 7, 9}, 51), b = reference::random_tensor(Shape{2, 2, 7, 9}, 52);
  const std::vector<float> w = reference::random_vector(4 * 5 * 9, 53, 0.5f), bias = reference::random_vector(4, 54);
  Tensor cat, y_ref, y;
  concat_forward(cat, a, b);
  conv2d_forward(y_ref, cat, w.data(), bias.data(), 4, 3, 1, true);
  conv2d_cat_forward(y, a, b, w.data(), bias.data(), 4, true);
  ASSERT_EQ(y.shape(), y_ref.shape());
  for (std::size_t i = 0; i < y.numel(); ++i) ASSERT_NEAR(y.data()[i], y_ref.data()[i], 1e-6f);

  const Tensor dy = reference::random_tensor(y.shape(), 55);
  Tensor d_cat, d_a_ref, d_b_ref, d_a, d_b;
  std::vector<float> dw_ref(w.size()), db_ref(4), dw(w.size()), db(4);
  conv2d_backward(&d_cat, dw_ref.data(), db_ref.data(), dy, y_ref, cat, w.data(), 3, 1, true);
  concat_backward(d_a_ref, d_b_ref, d_cat, 3, false);
  conv2d_cat_backward(d_a, d_b, dw.data(), db.data(), dy, y, a, b, w.data(), true);
  for (std::size_t i = 0; i < d_a.numel(); ++i) ASSERT_NEAR(d_a.data()[i], d_a_ref.data()[i], 1e-5f);
  for (std::size_t i = 0; i < d_b.numel(); ++i) ASSERT_NEAR(d_b.data()[i], d_b_ref.data()[i], 1e-5f);
  for (std::size_t i = 0; i < dw.size(); ++i) ASSERT_NEAR(dw[i], dw_ref[i], 1e-5f);
  for (std::size_t i = 0; i < db.size(); ++i) ASSERT_NEAR(db[i], db_ref[i], 1e-5f);
}

}  // namespace
}  // namespace lidarsim::nn

namespace lidarsim::nn {
namespace {

// Wide rows take the vectorised path (16 windows at a time) and the scalar tail; both must pick
// the first maximum in row order, also on ties.
TEST(MaxPool, VectorisedRowsAgreeWithTheReferenceIncludingTies) {
  Tensor x = reference::random_tensor(Shape{1, 2, 4, 70}, 61);
  for (int i = 0; i < 70; i += 3) x.at(0, 1, 0, i) = x.at(0, 1, 1, i) = 2.f;  // ties across rows
  Tensor y;
  std::vector<std::int32_t> am;
  max_pool2x2_forward(y, am, x);
  for (int c = 0; c < 2; ++c)
    for (int yy = 0; yy < 2; ++yy)
      for (int xx = 0; xx < 35; ++xx) {
        int best = 2 * yy * 70 + 2 * xx;
        for (int k : {2 * yy * 70 + 2 * xx + 1, (2 * yy + 1) * 70 + 2 * xx, (2 * yy + 1) * 70 + 2 * xx + 1})
          if (x.channel(0, c)[k] > x.channel(0, c)[best]) best = k;
        ASSERT_EQ(am[(c * 2 + yy) * 35 + xx], best) << c << " " << yy << " " << xx;
        ASSERT_EQ(y.at(0, c, yy, xx), x.channel(0, c)[best]);
      }
}

}  // namespace
}  // namespace lidarsim::nn
