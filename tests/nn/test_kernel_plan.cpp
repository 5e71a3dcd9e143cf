// The kernel plan (nn/kernel_plan.h): rule mode gives exactly the fixed rules; calibrated mode
// measures a candidate the CPU has, caches it on disk and a second plan reads it without timing;
// a corrupt cache is a warning and is measured again; a plan forced to the other algorithm for
// one layer gives other bits, and the gradients are right under either choice, pass by pass.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <tuple>
#include <vector>

#include "common/error.h"
#include "nn/kernel_cache.h"
#include "nn/kernel_calibration.h"
#include "nn/kernel_plan.h"
#include "nn/layers.h"
#include "nn/unet.h"
#include "nn/winograd.h"
#include "reference.h"
#include "tests/support/temp_path.h"

namespace lidarsim::nn {
namespace {

using namespace reference;
namespace fs = std::filesystem;

// LIDARSIM_KERNEL_CACHE pointed at a folder of this test's own (CI writes nothing outside its tree).
struct PlanTempCache {
  fs::path dir = lidarsim::testing::temp_path("kernel_cache");
  std::string old;
  bool had = false;
  PlanTempCache() {
    fs::remove_all(dir);
    fs::create_directories(dir);
    if (const char* o = std::getenv("LIDARSIM_KERNEL_CACHE")) old = o, had = true;
    ::setenv("LIDARSIM_KERNEL_CACHE", dir.c_str(), 1);
  }
  ~PlanTempCache() {
    if (had) ::setenv("LIDARSIM_KERNEL_CACHE", old.c_str(), 1);
    else ::unsetenv("LIDARSIM_KERNEL_CACHE");
  }
};

// Every 3x3 conv of unet-ref (3 inputs, base 16, depth 4, 64 x 1024) as ci -> co at h x w.
struct PlanConv {
  int ci, co, h, w;
};
std::vector<PlanConv> plan_unet_ref_convs() {
  std::vector<PlanConv> out;
  for (int l = 0; l <= 4; ++l) {
    const int c = 16 << l, h = 64 >> l, w = 1024 >> l;
    out.push_back({l == 0 ? 3 : c / 2, c, h, w});  // enc{l}.conv1
    out.push_back({c, c, h, w});                    // enc{l}.conv2
    if (l < 4) out.push_back({2 * c, c, h, w});     // dec{l}.conv1 (dec{l}.conv2 is c -> c, as above)
  }
  return out;
}

// The rules as nn/conv3x3.cpp and nn/conv3x3_bf16.cpp state them, written out independently.
ConvAlgo plan_expected_rule(const ConvKey& k) {
  const long pixels = static_cast<long>(k.n) * k.h * k.w;
  const int m = std::min(k.ci, k.co);
  if (k.pass == ConvPass::bf16_forward) {
    if (k.isa >= Isa::amx_bf16) return ConvAlgo::amx;
    if (m < 32) return ConvAlgo::avx512_bf16;
    return pixels < 2048 || pixels >= 32768 ? ConvAlgo::avx512_bf16 : ConvAlgo::fp32;
  }
  if (k.isa >= Isa::avx512) return m >= 16 ? ConvAlgo::winograd : ConvAlgo::direct;
  return pixels >= 1024 ? ConvAlgo::winograd : ConvAlgo::direct;
}

TEST(KernelPlan, RuleModeGivesTheFixedRulesOnEveryUnetRefShapeAtEveryLevel) {
  if (!detail::winograd_available()) GTEST_SKIP() << "built without the AVX2 kernels";
  for (int level = 0; level <= static_cast<int>(cpu_isa()); ++level) {
    const testhook::ScopedIsa isa(static_cast<Isa>(level));
    KernelPlan plan;
    int checked = 0;
    for (const int n : {1, 4})
      for (const PlanConv& c : plan_unet_ref_convs())
        for (const ConvPass pass : {ConvPass::forward, ConvPass::input_grad, ConvPass::weight_grad, ConvPass::bf16_forward}) {
          if (pass == ConvPass::bf16_forward && level < static_cast<int>(Isa::avx512_bf16)) continue;
          const ConvKey key{pass, n, c.ci, c.co, c.h, c.w, static_cast<Isa>(level)};
          EXPECT_EQ(plan.lookup(key), plan_expected_rule(key))
              << to_string(pass) << " n" << n << " " << c.ci << "->" << c.co << " " << c.h << "x" << c.w << " at "
              << to_string(static_cast<Isa>(level));
          ++checked;
        }
    EXPECT_EQ(plan.entries().size(), static_cast<std::size_t>(checked));  // each recorded once
  }
}

// A model consults its plan only while its 3x3 algorithm is automatic (LIDARSIM_CONV3X3 unset).
#define SKIP_UNLESS_AUTOMATIC()                                         \
  if (detail::conv3x3_path() != detail::Conv3x3Path::automatic) GTEST_SKIP() << "LIDARSIM_CONV3X3 forces the path"

TEST(KernelPlan, AModelRecordsEveryConvItRuns) {
  SKIP_UNLESS_AUTOMATIC();
  UNet model(UNetConfig{.in_channels = 3, .out_channels = 1, .base = 16, .depth = 1});
  model.init(3);
  Tensor x = random_tensor(Shape{1, 3, 16, 64}, 5), y;
  model.forward(x, y);
  model.backward(random_tensor(y.shape(), 6));
  const auto& e = model.kernel_plan().entries();
  const Isa isa = active_isa();
  EXPECT_EQ(e.count(ConvKey{ConvPass::forward, 1, 3, 16, 16, 64, isa}), 1u);
  EXPECT_EQ(e.count(ConvKey{ConvPass::forward, 1, 32, 16, 16, 64, isa}), 1u);  // dec0.conv1 over the concat
  EXPECT_EQ(e.count(ConvKey{ConvPass::weight_grad, 1, 16, 32, 8, 32, isa}), 1u);
  // The JSON carries every choice back.
  const KernelPlan back = KernelPlan::from_json(model.kernel_plan().to_json(), "test");
  EXPECT_EQ(back.entries(), e);
  EXPECT_EQ(back.mode(), PlanMode::rule);
}

TEST(KernelPlan, CalibratedModeMeasuresOnceAndTheCacheServesTheNextPlan) {
  const PlanTempCache cache;
  const ConvKey key{ConvPass::forward, 1, 16, 16, 16, 64, active_isa()};
  const long before = testhook::calibrations();
  KernelPlan first(PlanMode::calibrated);
  const ConvAlgo a = first.lookup(key);
  EXPECT_EQ(testhook::calibrations(), before + 1);
  const std::vector<ConvAlgo> cands = candidates(key);
  EXPECT_NE(std::find(cands.begin(), cands.end(), a), cands.end());
  EXPECT_EQ(first.entries().at(key).seconds.size(), cands.size());  // every candidate timed
  EXPECT_TRUE(fs::exists(kernel_cache_path(key.isa)));
  EXPECT_EQ(first.lookup(key), a);  // recorded: no second measurement
  KernelPlan second(PlanMode::calibrated);
  EXPECT_EQ(second.lookup(key), a);
  EXPECT_EQ(second.entries().at(key), first.entries().at(key));
  EXPECT_EQ(testhook::calibrations(), before + 1);  // read from the file, not timed
}

TEST(KernelPlan, ACorruptCacheIsAWarningNamingTheFileAndIsMeasuredAgain) {
  const PlanTempCache cache;
  const ConvKey key{ConvPass::forward, 1, 8, 8, 8, 32, active_isa()};
  const fs::path path = kernel_cache_path(key.isa);
  std::ofstream(path) << "{\"mode\": \"calibrated\", \"choices\": [{\"pass\": \"forward\"";  // torn
  const long before = testhook::calibrations();
  ::testing::internal::CaptureStderr();
  KernelPlan plan(PlanMode::calibrated);
  plan.lookup(key);
  const std::string err = ::testing::internal::GetCapturedStderr();
  EXPECT_NE(err.find(path.string()), std::string::npos) << err;
  EXPECT_NE(err.find("warning"), std::string::npos) << err;
  EXPECT_EQ(testhook::calibrations(), before + 1);
  EXPECT_EQ(read_kernel_cache(key.isa).count(key), 1u);  // rewritten whole
}

TEST(KernelPlan, BadPlanJsonNamesTheField) {
  try {
    KernelPlan::from_json(R"({"mode":"rule","choices":[{"pass":"forward","n":1,"ci":3,"co":16,"h":8,"w":8,)"
                          R"("isa":"avx2","algo":"amx"}]})",
                          "ckpt.h5: /config/kernel_plan");
    FAIL() << "accepted amx for an fp32 pass";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("choices[0]"), std::string::npos) << e.what();
  }
  EXPECT_THROW(parse_plan_mode("x", "--kernels"), Error);
}

// The other candidate than the rule's, for `key` (the test needs one).
ConvAlgo plan_other_than_rule(const ConvKey& key) {
  const std::vector<ConvAlgo> c = candidates(key);
  return c.size() > 1 ? c[1] : c[0];
}

TEST(KernelPlan, AForcedNonRuleChoiceForOneLayerGivesOtherBits) {
  if (!detail::winograd_available()) GTEST_SKIP() << "built without the AVX2 kernels";
  SKIP_UNLESS_AUTOMATIC();
  const UNetConfig config{.in_channels = 3, .out_channels = 1, .base = 16, .depth = 1};
  UNet rule_model(config), forced_model(config);
  rule_model.init(3);
  forced_model.init(3);
  const ConvKey enc0_conv2{ConvPass::forward, 1, 16, 16, 16, 64, active_isa()};
  KernelPlan forced;
  forced.set(enc0_conv2, plan_other_than_rule(enc0_conv2));
  forced_model.set_kernel_plan(forced);
  const Tensor x = random_tensor(Shape{1, 3, 16, 64}, 5);
  Tensor a, b;
  rule_model.forward(x, a);
  forced_model.forward(x, b);
  EXPECT_FALSE(std::equal(a.begin(), a.end(), b.begin())) << "the forced choice did not change a bit";
  double worst = 0;
  for (std::size_t i = 0; i < a.numel(); ++i) worst = std::max(worst, std::abs(double(a.data()[i]) - b.data()[i]));
  EXPECT_LT(worst, 1e-4);  // the same conv, summed in another order
  EXPECT_EQ(forced_model.kernel_plan().entries().at(enc0_conv2).algo, plan_other_than_rule(enc0_conv2));
}

// The finite-difference check of tests/nn/test_layers_gradcheck.cpp under a plan that forces each
// pass: both algorithms alone, and mixed across the passes.
TEST(KernelPlan, GradientsMatchFiniteDifferencesUnderEitherChoicePerPass) {
  if (!detail::winograd_available()) GTEST_SKIP() << "built without the AVX2 kernels";
  const int n = 1, ci = 9, co = 10, h = 6, w = 13;
  const Tensor x = random_tensor(Shape{n, ci, h, w}, 1);
  const std::vector<float> wt = random_vector(std::size_t(co) * ci * 9, 2, 0.5f);
  const std::vector<float> bias = random_vector(std::size_t(co), 3, 0.3f);
  DT xd = from(x);
  std::vector<double> wd(wt.begin(), wt.end()), bd(bias.begin(), bias.end());
  const ConvAlgo D = ConvAlgo::direct, W = ConvAlgo::winograd;
  for (const auto& [f, i, g] : {std::tuple{D, D, D}, std::tuple{W, W, W}, std::tuple{W, D, W}, std::tuple{D, W, D}}) {
    SCOPED_TRACE(std::string("forward ") + to_string(f) + ", input_grad " + to_string(i) + ", weight_grad " + to_string(g));
    KernelPlan plan;
    const Isa isa = active_isa();
    plan.set(ConvKey{ConvPass::forward, n, ci, co, h, w, isa}, f);
    plan.set(ConvKey{ConvPass::input_grad, n, ci, co, h, w, isa}, i);
    plan.set(ConvKey{ConvPass::weight_grad, n, ci, co, h, w, isa}, g);
    detail::ConvSettings cs;
    cs.conv3x3 = detail::Conv3x3Path::automatic;
    cs.plan = &plan;
    Tensor y;
    conv2d_forward(y, x, wt.data(), bias.data(), co, 3, 1, true, cs);
    const Tensor r = random_tensor(y.shape(), 4);
    const std::vector<double> rd(r.begin(), r.end());
    Tensor d_in;
    std::vector<float> dw(wt.size(), 0.f), db(bias.size(), 0.f);
    conv2d_backward(&d_in, dw.data(), db.data(), r, y, x, wt.data(), 3, 1, true, cs);
    auto loss = [&] { return dot(conv2d(xd, wd, bd, co, 3, 1, true), rd); };
    EXPECT_LT(max_rel_error(y.data(), conv2d(xd, wd, bd, co, 3, 1, true).v), 1e-5);
    EXPECT_LT(max_rel_error(d_in.data(), numeric_gradient(xd.v, loss)), 1e-4);
    EXPECT_LT(max_rel_error(dw.data(), numeric_gradient(wd, loss)), 1e-4);
    EXPECT_LT(max_rel_error(db.data(), numeric_gradient(bd, loss)), 1e-4);
    EXPECT_EQ(plan.entries().size(), 3u);  // nothing looked up beyond the forced keys
  }
}

}  // namespace
}  // namespace lidarsim::nn
