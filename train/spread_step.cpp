// A training step's gradients with a spread head (train/spread_step.h).
#include "train/spread_step.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "nn/loss.h"

namespace lidarsim::train {

namespace {

// The output parameters of channel `k` alone: its row of the 1x1 head (weights [K, C, 1, 1] and
// bias [K]) and, with row_affine, its gain and offset per row ([1, K, rows, 1]). (offset, count)
std::vector<std::pair<std::size_t, std::size_t>> channel_slices(const nn::ParamArena& params, int k, int channels) {
  std::vector<std::pair<std::size_t, std::size_t>> slices;
  for (const std::string name : {"head/weight", "head/bias", "row_affine/gain", "row_affine/offset"}) {
    const int id = params.find(name);
    if (id < 0) continue;
    const std::size_t per = params.info(id).shape.numel() / static_cast<std::size_t>(channels);
    slices.emplace_back(params.info(id).offset + per * static_cast<std::size_t>(k), per);
  }
  return slices;
}

}  // namespace

double spread_step_gradients(nn::UNet& model, const std::vector<nn::HeadKind>& heads, const nn::Tensor& x,
                             const nn::Tensor& y, const nn::Tensor& m, float spread_weight, float lambda, double* l2,
                             SpreadStepBuffers& b) {
  nn::Tensor &pred = b.pred, &d_pred = b.d_pred, &d_spread = b.d_spread;
  std::vector<float>& spread_grads = b.spread_grads;
  model.forward(x, pred);
  std::vector<nn::HeadTarget> targets;
  for (const nn::HeadKind h : heads)
    if (h == nn::HeadKind::zero_logit) {
      nn::zero_indicator(b.zero_target, y);  // the zero head: BCE on the cells with a return
      targets.push_back({&b.zero_target, &m});
    } else {
      targets.push_back({&y, &m, h == nn::HeadKind::mean ? 1.f : spread_weight});
    }
  const nn::HeadsLoss loss = nn::heads_loss(heads, pred, targets, &d_pred);
  const std::size_t plane = static_cast<std::size_t>(pred.shape().h) * pred.shape().w;
  const int n = pred.shape().n, k = pred.shape().c;
  // The other heads' channels' gradients alone.
  d_spread.resize(pred.shape());
  std::fill(d_spread.begin(), d_spread.end(), 0.f);
  for (int b = 0; b < n; ++b)
    for (int c = 1; c < k; ++c) {
      const std::size_t at = (static_cast<std::size_t>(b) * k + c) * plane;
      std::copy_n(d_pred.data() + at, plane, d_spread.data() + at);
      std::fill_n(d_pred.data() + at, plane, 0.f);
    }
  nn::ParamArena& params = model.params();
  model.backward(d_spread);
  // Channel c's own output parameters see only channel c's loss, so one backward pass serves
  // every head after the mean.
  spread_grads.clear();
  std::vector<std::pair<std::size_t, std::size_t>> slices;
  for (int c = 1; c < k; ++c)
    for (const auto& slice : channel_slices(params, c, k)) slices.push_back(slice);
  for (const auto& [offset, count] : slices) spread_grads.insert(spread_grads.end(), params.grads() + offset, params.grads() + offset + count);
  params.zero_grads();
  *l2 = nn::l2_penalty(params, lambda, true);
  // The L2 term of the other heads' own parameters, added to their gradients below.
  std::vector<float>& l2_grads = b.l2_grads;
  l2_grads.clear();
  for (const auto& [offset, count] : slices) l2_grads.insert(l2_grads.end(), params.grads() + offset, params.grads() + offset + count);
  model.backward(d_pred);  // the mean's MSE: every shared layer, and channel 0's own parameters
  std::size_t at = 0;
  for (const auto& [offset, count] : slices)
    for (std::size_t i = 0; i < count; ++i, ++at) params.grads()[offset + i] = spread_grads[at] + l2_grads[at];
  return loss.total;
}

void start_spread_at(nn::UNet& model, const nn::Tensor& y, const nn::Tensor& m) {
  double sum = 0, count = 0;
  for (std::size_t i = 0; i < m.numel(); ++i)
    if (m.data()[i] > 0) sum += y.data()[i], count += 1;
  if (count == 0) return;
  const double mean = sum / count;
  double dev = 0;
  for (std::size_t i = 0; i < m.numel(); ++i)
    if (m.data()[i] > 0) dev += std::abs(y.data()[i] - mean);
  const int bias = model.params().find("head/bias");
  model.params().value(bias)[1] = static_cast<float>(std::log(std::max(dev / count, 1e-3)));
  // A zero head starts at the logit of the batch's share of zeros (kept inside [0.001, 0.999]).
  const int zc = nn::head_channel(model.config().heads, nn::HeadKind::zero_logit);
  if (zc < 0) return;
  double zeros = 0;
  for (std::size_t i = 0; i < m.numel(); ++i) zeros += m.data()[i] > 0 && y.data()[i] <= 0;
  const double share = std::clamp(zeros / count, 1e-3, 1 - 1e-3);
  model.params().value(bias)[zc] = static_cast<float>(std::log(share / (1 - share)));
}

}  // namespace lidarsim::train
