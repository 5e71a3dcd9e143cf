// Agreement with PyTorch, the field's reference: tests/fixtures/unet_small_torch.h5 holds a
// small UNet's weights, inputs, PyTorch's forward output, loss, gradients and the weights after
// one Adam step (written by tests/fixtures/make_torch_fixture.py, computed in float64). No
// Python runs here: the fixture is read with the HDF5 C API.
#include <gtest/gtest.h>
#include <hdf5.h>

#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "conv_path.h"
#include "nn/loss.h"
#include "nn/optim.h"
#include "nn/unet.h"
#include "nn/winograd.h"
#include "tests/support/shared_data.h"

using namespace lidarsim::nn;

namespace {

// Tolerances from the issue; float32 PyTorch itself lands at ~1e-6 (forward) and ~4e-8 (after
// the step) from the float64 reference, as make_torch_fixture.py prints.
constexpr double kForwardTol = 1e-4;
constexpr double kTorchLossTol = 1e-4;
constexpr double kTorchGradTol = 1e-3;
constexpr double kAfterStepTol = 1e-3;

class TorchFixture {
 public:
  TorchFixture() {
    H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
    path_ = (lidarsim::testing::source_dir() / "tests/fixtures/unet_small_torch.h5").string();
    file_ = H5Fopen(path_.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  }
  ~TorchFixture() {
    if (file_ >= 0) H5Fclose(file_);
  }
  bool ok() const { return file_ >= 0; }
  const std::string& path() const { return path_; }

  bool has(const std::string& p) const { return H5Lexists(file_, p.c_str(), H5P_DEFAULT) > 0; }

  // Any numeric dataset as doubles, with its dims; empty when absent.
  std::vector<double> read(const std::string& p, std::vector<hsize_t>* dims = nullptr) const {
    std::vector<double> out;
    hid_t set = H5Dopen2(file_, p.c_str(), H5P_DEFAULT);
    if (set < 0) return out;
    hid_t space = H5Dget_space(set);
    std::vector<hsize_t> d(static_cast<std::size_t>(H5Sget_simple_extent_ndims(space)));
    H5Sget_simple_extent_dims(space, d.data(), nullptr);
    out.resize(static_cast<std::size_t>(H5Sget_simple_extent_npoints(space)));
    if (H5Dread(set, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, out.data()) < 0) out.clear();
    H5Sclose(space);
    H5Dclose(set);
    if (dims) *dims = d;
    return out;
  }

  double attr(const std::string& obj, const std::string& name) const {
    double v = std::nan("");
    hid_t a = H5Aopen_by_name(file_, obj.c_str(), name.c_str(), H5P_DEFAULT, H5P_DEFAULT);
    if (a >= 0) {
      H5Aread(a, H5T_NATIVE_DOUBLE, &v);
      H5Aclose(a);
    }
    return v;
  }

  Tensor tensor(const std::string& p) const {
    std::vector<hsize_t> d;
    const std::vector<double> v = read(p, &d);
    if (d.size() != 4) return {};
    Tensor t(static_cast<int>(d[0]), static_cast<int>(d[1]), static_cast<int>(d[2]), static_cast<int>(d[3]));
    for (std::size_t i = 0; i < v.size(); ++i) t.data()[i] = static_cast<float>(v[i]);
    return t;
  }

 private:
  std::string path_;
  hid_t file_ = -1;
};

// ||a - b|| / ||b|| in double.
double torch_rel_error(const float* a, const double* b, std::size_t n) {
  double num = 0, den = 0;
  for (std::size_t i = 0; i < n; ++i) {
    num += (a[i] - b[i]) * (a[i] - b[i]);
    den += b[i] * b[i];
  }
  return std::sqrt(num) / std::max(std::sqrt(den), 1e-30);
}

UNetConfig fixture_config(const TorchFixture& f) {
  return UNetConfig{static_cast<int>(f.attr("config", "in_channels")), static_cast<int>(f.attr("config", "out_channels")),
                    static_cast<int>(f.attr("config", "base")), static_cast<int>(f.attr("config", "depth"))};
}

// Loads the fixture's initial weights into `model` by name, checking each size.
void load_initial_weights(const TorchFixture& f, UNet& model) {
  ParamArena& params = model.params();
  for (const ParamInfo& info : params.infos()) {
    const std::vector<double> v = f.read("params/" + info.name);
    ASSERT_EQ(v.size(), info.shape.numel()) << "fixture params/" << info.name;
    for (std::size_t i = 0; i < v.size(); ++i) params.values()[info.offset + i] = static_cast<float>(v[i]);
  }
}

void check_case(const std::string& name, detail::Conv3x3Path path = detail::Conv3x3Path::direct) {
  conv_paths::Conv3x3PathGuard guard(path);
  TorchFixture f;
  ASSERT_TRUE(f.ok()) << "cannot open " << f.path() << " (regenerate: /usr/bin/python3 tests/fixtures/make_torch_fixture.py)";
  const std::string c = "cases/" + name + "/";
  ASSERT_TRUE(f.has("cases/" + name)) << f.path() << ": no case " << name;

  UNet model(fixture_config(f));
  load_initial_weights(f, model);
  const Tensor x = f.tensor(c + "input"), target = f.tensor(c + "target"), mask = f.tensor(c + "mask");
  std::vector<hsize_t> out_dims;
  const std::vector<double> ref_out = f.read(c + "output", &out_dims);
  ASSERT_EQ(out_dims.size(), 4u);

  // Forward.
  Tensor y;
  model.params().zero_grads();
  model.forward(x, y);
  ASSERT_EQ(y.shape(), (Shape{static_cast<int>(out_dims[0]), static_cast<int>(out_dims[1]),
                              static_cast<int>(out_dims[2]), static_cast<int>(out_dims[3])}));
  const double fwd = torch_rel_error(y.data(), ref_out.data(), ref_out.size());
  EXPECT_LT(fwd, kForwardTol) << "forward output vs PyTorch";

  // predict() must give the same answer as forward().
  Tensor y_pred;
  model.predict(x, y_pred);
  EXPECT_LT(torch_rel_error(y_pred.data(), ref_out.data(), ref_out.size()), kForwardTol) << "predict vs PyTorch";

  // Loss: masked MSE + lambda * sum(w^2).
  const float lambda = static_cast<float>(f.attr("config", "lambda"));
  Tensor dy(y.shape());
  const LossParts parts = masked_mse(y, target, mask, &dy);
  const double l2 = l2_penalty(model.params(), lambda, true);
  const double loss = parts.data + l2, ref_loss = f.attr("cases/" + name, "loss");
  EXPECT_LT(std::abs(parts.data - f.attr("cases/" + name, "loss_data")) / f.attr("cases/" + name, "loss_data"),
            kTorchLossTol)
      << "data term " << parts.data;
  EXPECT_LT(std::abs(l2 - f.attr("cases/" + name, "loss_l2")) / f.attr("cases/" + name, "loss_l2"), kTorchLossTol)
      << "L2 term " << l2;
  EXPECT_LT(std::abs(loss - ref_loss) / ref_loss, kTorchLossTol) << "loss " << loss << " vs PyTorch " << ref_loss;

  // Gradients (a diagnostic between the loss and the step: names the first wrong layer).
  model.backward(dy);
  double worst_grad = 0;
  for (const ParamInfo& info : model.params().infos()) {
    const std::vector<double> g = f.read(c + "grads/" + info.name);
    ASSERT_EQ(g.size(), info.shape.numel());
    const double e = torch_rel_error(model.params().grad(model.params().find(info.name)), g.data(), g.size());
    EXPECT_LT(e, kTorchGradTol) << "gradient of " << info.name;
    worst_grad = std::max(worst_grad, e);
  }

  // One Adam step (PyTorch defaults).
  OptimizerConfig oc;
  oc.kind = OptimizerKind::Adam;
  oc.lr = static_cast<float>(f.attr("config", "lr"));
  oc.beta1 = static_cast<float>(f.attr("config", "beta1"));
  oc.beta2 = static_cast<float>(f.attr("config", "beta2"));
  oc.eps = static_cast<float>(f.attr("config", "eps"));
  Optimizer opt(oc, model.params().size());
  const std::vector<float> before(model.params().values(), model.params().values() + model.params().size());
  opt.step(model.params());
  double worst_after = 0;
  for (const ParamInfo& info : model.params().infos()) {
    const std::vector<double> w = f.read(c + "params_after/" + info.name);
    ASSERT_EQ(w.size(), info.shape.numel());
    const double e = torch_rel_error(model.params().value(model.params().find(info.name)), w.data(), w.size());
    EXPECT_LT(e, kAfterStepTol) << "weights after one Adam step: " << info.name;
    worst_after = std::max(worst_after, e);
  }
  // The update itself (~lr per weight) is ~100x smaller than the weights, so also compare it
  // alone over the whole arena: a wrong Adam formula hides less well here. Looser, because a
  // gradient within float32 noise of zero may flip the sign of its ~lr-sized update.
  double num = 0, den = 0;
  for (const ParamInfo& info : model.params().infos()) {
    const std::vector<double> w = f.read(c + "params_after/" + info.name);
    const float* ours = model.params().values() + info.offset;
    for (std::size_t i = 0; i < w.size(); ++i) {
      const double ref_step = w[i] - before[info.offset + i];
      const double our_step = double(ours[i]) - before[info.offset + i];
      num += (our_step - ref_step) * (our_step - ref_step);
      den += ref_step * ref_step;
    }
  }
  const double step_err = std::sqrt(num / den);
  EXPECT_LT(step_err, 1e-2) << "the Adam update (after - before) vs PyTorch's";
  std::printf("[ measured ] %s (%s): forward %.2e, loss %.2e, worst gradient %.2e, worst after-step %.2e, update %.2e\n",
              name.c_str(), conv_paths::path_name(path), fwd, std::abs(loss - ref_loss) / ref_loss, worst_grad, worst_after, step_err);
}

}  // namespace

TEST(TorchAgreement, FixtureHoldsEveryParameterOfTheModel) {
  TorchFixture f;
  ASSERT_TRUE(f.ok()) << f.path();
  UNet model(fixture_config(f));
  EXPECT_EQ(model.params().infos().size(), 26u);  // depth 2: 5 double convs + 2 ups + head, weight + bias
  for (const ParamInfo& info : model.params().infos()) {
    std::vector<hsize_t> dims;
    f.read("params/" + info.name, &dims);
    ASSERT_FALSE(dims.empty()) << "fixture lacks params/" << info.name;
    std::size_t n = 1;
    for (hsize_t d : dims) n *= d;
    EXPECT_EQ(n, info.shape.numel()) << info.name;
  }
}

TEST(TorchAgreement, ForwardLossGradientsAndOneAdamStepMatchPyTorchOnEvenSize) { check_case("even"); }

// 13 x 21 does not divide by 2^depth: exercises the floor max-pool and the pad-to-skip.
TEST(TorchAgreement, ForwardLossGradientsAndOneAdamStepMatchPyTorchOnOddSize) { check_case("odd"); }

// The same fixture with the 3x3 convolutions on Winograd F(4x4, 3x3) (forward, input gradient).
TEST(TorchAgreement, WinogradPathMatchesPyTorchOnEvenAndOddSize) {
  if (!detail::winograd_available()) GTEST_SKIP() << "built without AVX2 kernels (LIDARSIM_ARCH below x86-64-v3): no Winograd path";
  check_case("even", detail::Conv3x3Path::winograd);
  check_case("odd", detail::Conv3x3Path::winograd);
}
