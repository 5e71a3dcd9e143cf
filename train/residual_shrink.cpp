#include "train/residual_shrink.h"

#include <string>

#include "common/error.h"

namespace lidarsim::train {

namespace {
// The parameters whose product with `factor` scales the residual.
std::vector<int> residual_params(const nn::UNet& model) {
  const nn::ParamArena& p = model.params();
  if (p.find("lookup/table") < 0) throw Error("shrink-residual: the model has no lookup base (train with --lookup-base)");
  const int gain = p.find("row_affine/gain"), offset = p.find("row_affine/offset");
  if (gain >= 0 && offset >= 0) return {gain, offset};
  const int w = p.find("head/weight"), b = p.find("head/bias");
  if (w < 0 || b < 0) throw Error("shrink-residual: the model has no head/weight and head/bias");
  return {w, b};
}
}  // namespace

void scale_residual(nn::UNet& model, double factor) {
  nn::ParamArena& p = model.params();
  for (int id : residual_params(model)) {
    float* v = p.value(id);
    for (std::size_t i = 0; i < p.info(id).shape.numel(); ++i) v[i] = static_cast<float>(v[i] * factor);
  }
}

ResidualShrink choose_residual_scale(nn::UNet& model, const std::function<double()>& inner_mae) {
  nn::ParamArena& p = model.params();
  const std::vector<int> ids = residual_params(model);
  std::vector<std::vector<float>> trained;
  for (int id : ids) trained.emplace_back(p.value(id), p.value(id) + p.info(id).shape.numel());
  auto set = [&](double factor) {
    for (std::size_t k = 0; k < ids.size(); ++k) {
      float* v = p.value(ids[k]);
      for (std::size_t i = 0; i < trained[k].size(); ++i) v[i] = static_cast<float>(trained[k][i] * factor);
    }
  };
  ResidualShrink out;
  double best = 0;
  for (int step = 20; step >= 0; --step) {  // from 1 down: ties keep the larger factor
    const double factor = step / 20.0;
    set(factor);
    const double mae = inner_mae();
    out.inner_mae.emplace_back(factor, mae);
    if (out.inner_mae.size() == 1 || mae < best) best = mae, out.scale = factor;
  }
  set(out.scale);
  return out;
}

}  // namespace lidarsim::train
