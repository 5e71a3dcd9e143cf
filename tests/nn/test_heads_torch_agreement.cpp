// The heads' losses, the sigmoid and a three-head UNet against PyTorch: tests/fixtures/heads_losses_torch.h5 holds
// inputs, PyTorch's float64 loss and autograd gradients (binary_cross_entropy_with_logits,
// torch.sigmoid, distributions.Normal / Laplace log_prob with a clamped log-scale), written by
// tests/fixtures/make_heads_fixture.py. Read with the HDF5 C API: no Python runs here.
#include <gtest/gtest.h>
#include <hdf5.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "nn/heads.h"
#include "nn/loss.h"
#include "nn/unet.h"
#include "tests/support/shared_data.h"

namespace lidarsim::nn {
namespace {

// float32 inputs computed in double on our side: the loss within 1e-6, gradients (float32)
// within 1e-6 in relative L2 norm (float rounding is ~6e-8).
constexpr double kLossTol = 1e-6;
constexpr double kGradTol = 1e-6;

class Fixture {
 public:
  Fixture() {
    H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
    path_ = (lidarsim::testing::source_dir() / "tests/fixtures/heads_losses_torch.h5").string();
    file_ = H5Fopen(path_.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  }
  ~Fixture() {
    if (file_ >= 0) H5Fclose(file_);
  }
  bool ok() const { return file_ >= 0; }
  const std::string& path() const { return path_; }

  std::vector<double> read(const std::string& p, std::vector<hsize_t>* dims = nullptr) const {
    std::vector<double> out;
    const hid_t set = H5Dopen2(file_, p.c_str(), H5P_DEFAULT);
    if (set < 0) return out;
    const hid_t space = H5Dget_space(set);
    std::vector<hsize_t> d(static_cast<std::size_t>(H5Sget_simple_extent_ndims(space)));
    H5Sget_simple_extent_dims(space, d.data(), nullptr);
    out.resize(static_cast<std::size_t>(H5Sget_simple_extent_npoints(space)));
    if (H5Dread(set, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, out.data()) < 0) out.clear();
    H5Sclose(space);
    H5Dclose(set);
    if (dims) *dims = d;
    return out;
  }
  Tensor tensor(const std::string& p) const {
    std::vector<hsize_t> d;
    const std::vector<double> v = read(p, &d);
    if (d.size() != 4) return {};
    Tensor t(static_cast<int>(d[0]), static_cast<int>(d[1]), static_cast<int>(d[2]), static_cast<int>(d[3]));
    for (std::size_t i = 0; i < v.size(); ++i) t.data()[i] = static_cast<float>(v[i]);
    return t;
  }
  double attr(const std::string& obj, const std::string& name) const {
    double v = std::nan("");
    const hid_t a = H5Aopen_by_name(file_, obj.c_str(), name.c_str(), H5P_DEFAULT, H5P_DEFAULT);
    if (a >= 0) {
      H5Aread(a, H5T_NATIVE_DOUBLE, &v);
      H5Aclose(a);
    }
    return v;
  }

 private:
  std::string path_;
  hid_t file_ = -1;
};

double rel_error(const Tensor& a, const std::vector<double>& b) {
  double num = 0, den = 0;
  for (std::size_t i = 0; i < b.size(); ++i) {
    num += (a.data()[i] - b[i]) * (a.data()[i] - b[i]);
    den += b[i] * b[i];
  }
  return a.numel() == b.size() ? std::sqrt(num) / std::max(std::sqrt(den), 1e-30) : INFINITY;
}

#define OPEN_FIXTURE(f)                                                                          \
  Fixture f;                                                                                     \
  ASSERT_TRUE(f.ok()) << "cannot open " << f.path()                                              \
                      << " (regenerate: /usr/bin/python3 tests/fixtures/make_heads_fixture.py)"

TEST(HeadsTorchAgreement, BceOnLogitsLossAndGradientIncludingExtremeLogits) {
  OPEN_FIXTURE(f);
  const Tensor z = f.tensor("bce/logit"), y = f.tensor("bce/target"), m = f.tensor("bce/mask");
  ASSERT_GT(z.numel(), 0u);
  Tensor g;
  const LossParts parts = masked_bce_logits(z, y, m, &g);
  const double want = f.attr("bce", "loss");
  EXPECT_LT(std::abs(parts.data - want) / want, kLossTol) << parts.data << " vs PyTorch " << want;
  EXPECT_LT(rel_error(g, f.read("bce/grad_logit")), kGradTol);
}

TEST(HeadsTorchAgreement, SigmoidIncludingExtremeInputs) {
  OPEN_FIXTURE(f);
  Tensor y;
  sigmoid_forward(y, f.tensor("sigmoid/input"));
  const std::vector<double> want = f.read("sigmoid/output");
  ASSERT_EQ(y.numel(), want.size());
  double worst = 0;
  for (std::size_t i = 0; i < want.size(); ++i) worst = std::max(worst, std::abs(y.data()[i] - want[i]));
  EXPECT_LT(worst, 1e-7);
}

struct TorchNllErrors {
  double loss = 0, d_mean = 0, d_log_scale = 0;
};

TorchNllErrors nll_errors(const Fixture& f, const std::string& name, Spread family) {
  const Tensor mu = f.tensor(name + "/mean"), s = f.tensor(name + "/log_scale"), y = f.tensor(name + "/target"),
               m = f.tensor(name + "/mask");
  const LogScaleClamp clamp{static_cast<float>(f.attr(name, "clamp_min")), static_cast<float>(f.attr(name, "clamp_max"))};
  Tensor gm, gs;
  const LossParts parts = masked_nll(family, mu, s, y, m, &gm, &gs, 0, clamp);
  const double want = f.attr(name, "loss");
  return {std::abs(parts.data - want) / std::abs(want), rel_error(gm, f.read(name + "/grad_mean")),
          rel_error(gs, f.read(name + "/grad_log_scale"))};
}

TEST(HeadsTorchAgreement, GaussianAndLaplaceNllLossAndBothGradientsWithTheClamp) {
  OPEN_FIXTURE(f);
  ASSERT_EQ(f.attr("gaussian", "clamp_min"), LogScaleClamp{}.min) << "the fixture's clamp is the default";
  ASSERT_EQ(f.attr("gaussian", "clamp_max"), LogScaleClamp{}.max);
  for (const auto& [name, family] : {std::pair{"gaussian", Spread::gaussian}, std::pair{"laplace", Spread::laplace}}) {
    SCOPED_TRACE(name);
    const TorchNllErrors e = nll_errors(f, name, family);
    std::printf("[ measured ] %s vs PyTorch: loss %.1e, d_mean %.1e, d_log_scale %.1e\n", name, e.loss, e.d_mean,
                e.d_log_scale);
    EXPECT_LT(e.loss, kLossTol);
    EXPECT_LT(e.d_mean, kGradTol);
    EXPECT_LT(e.d_log_scale, kGradTol);
  }
}

// The fixture tells the families apart: each one's answer fails the other's reference.
TEST(HeadsTorchAgreement, TheWrongFamilyFailsTheCheck) {
  OPEN_FIXTURE(f);
  const TorchNllErrors a = nll_errors(f, "gaussian", Spread::laplace), b = nll_errors(f, "laplace", Spread::gaussian);
  EXPECT_GT(std::max({a.loss, a.d_mean, a.d_log_scale}), 1e-2);
  EXPECT_GT(std::max({b.loss, b.d_mean, b.d_log_scale}), 1e-2);
}

// The three-head UNet end to end: forward, heads_loss (weights 1, 0.5, 0.25; the spread around the
// detached mean) and backward against PyTorch's autograd, every parameter.
TEST(HeadsTorchAgreement, ThreeHeadUNetOutputLossAndEveryGradient) {
  OPEN_FIXTURE(f);
  const std::vector<HeadKind> heads{HeadKind::mean, HeadKind::return_logit, HeadKind::log_scale_laplace};
  UNet model(UNetConfig{3, 3, 4, 2, 0, {}, heads});
  ParamArena& params = model.params();
  for (const ParamInfo& info : params.infos()) {
    const std::vector<double> v = f.read("unet3/params/" + info.name);
    ASSERT_EQ(v.size(), info.shape.numel()) << "fixture unet3/params/" << info.name;
    for (std::size_t i = 0; i < v.size(); ++i) params.values()[info.offset + i] = static_cast<float>(v[i]);
  }
  const Tensor x = f.tensor("unet3/input"), intensity = f.tensor("unet3/intensity"),
               returned = f.tensor("unet3/returned"), m_int = f.tensor("unet3/mask_intensity"),
               m_ret = f.tensor("unet3/mask_returned");
  Tensor y, dy;
  params.zero_grads();
  model.forward(x, y);
  const double out_err = rel_error(y, f.read("unet3/output"));
  const HeadsLoss loss =
      heads_loss(heads, y, {{&intensity, &m_int, 1.f}, {&returned, &m_ret, 0.5f}, {&intensity, &m_int, 0.25f}}, &dy);
  model.backward(dy);
  const double want = f.attr("unet3", "loss");
  double worst = 0;
  std::string worst_name;
  for (const ParamInfo& info : params.infos()) {
    const std::vector<double> g = f.read("unet3/grads/" + info.name);
    Tensor ours(Shape{1, 1, 1, static_cast<int>(info.shape.numel())});
    std::copy_n(params.grads() + info.offset, info.shape.numel(), ours.data());
    const double e = rel_error(ours, g);
    if (e > worst) worst = e, worst_name = info.name;
  }
  std::printf("[ measured ] three-head UNet vs PyTorch: output %.1e, loss %.1e, worst gradient %.1e (%s)\n", out_err,
              std::abs(loss.total - want) / want, worst, worst_name.c_str());
  EXPECT_LT(out_err, 1e-5);
  EXPECT_LT(std::abs(loss.total - want) / want, 1e-5);
  EXPECT_LT(worst, 1e-4) << worst_name;
}

}  // namespace
}  // namespace lidarsim::nn
