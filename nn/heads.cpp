#include "nn/heads.h"

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>

#include "common/error.h"

namespace lidarsim::nn {

const char* head_name(HeadKind kind) {
  const auto i = static_cast<std::size_t>(kind);
  return i < kHeadNames.size() ? kHeadNames[i] : "?";
}

std::string heads_text(const std::vector<HeadKind>& heads) {
  std::string out;
  for (std::size_t i = 0; i < heads.size(); ++i) out += (i ? "," : "") + std::string(head_name(heads[i]));
  return out;
}

std::vector<HeadKind> parse_heads(const std::string& text, const std::string& where) {
  std::vector<HeadKind> heads;
  std::size_t start = 0;
  while (start <= text.size()) {
    const std::size_t comma = std::min(text.find(',', start), text.size());
    const std::string name = text.substr(start, comma - start);
    const auto it = std::find_if(kHeadNames.begin(), kHeadNames.end(), [&](const char* n) { return name == n; });
    if (it == kHeadNames.end()) {
      std::string known;
      for (const char* n : kHeadNames) known += (known.empty() ? "" : ", ") + std::string(n);
      throw Error(where + ": unknown head \"" + name + "\" (known: " + known + ")");
    }
    heads.push_back(static_cast<HeadKind>(it - kHeadNames.begin()));
    start = comma + 1;
  }
  return heads;
}

void check_heads(const std::vector<HeadKind>& heads, int out_channels, const std::string& where) {
  if (heads.empty()) return;
  const auto fail = [&](const std::string& what) { throw Error(where + ": " + what + " (got \"" + heads_text(heads) + "\")"); };
  if (static_cast<int>(heads.size()) != out_channels)
    fail("expected one head per output channel, " + std::to_string(out_channels));
  if (heads[0] != HeadKind::mean) fail("channel 0 must be the mean head");
  int count[static_cast<int>(HeadKind::count)] = {};
  for (HeadKind h : heads) {
    if (static_cast<int>(h) < 0 || h >= HeadKind::count) fail("unknown head kind");
    ++count[static_cast<int>(h)];
  }
  for (int h = 0; h < static_cast<int>(HeadKind::count); ++h)
    if (count[h] > 1) fail(std::string("head \"") + head_name(static_cast<HeadKind>(h)) + "\" appears more than once");
  const int spreads = count[static_cast<int>(HeadKind::log_scale_gaussian)] + count[static_cast<int>(HeadKind::log_scale_laplace)];
  if (spreads > 1) fail("at most one spread head (log_scale_gaussian or log_scale_laplace)");
  if (count[static_cast<int>(HeadKind::zero_logit)] > 0 && spreads == 0)
    fail("zero_logit needs a spread head (a draw that is not 0 comes from the spread)");
}

namespace {

void copy_channel(Tensor& out, const Tensor& in, int c) {
  const Shape s = in.shape();
  if (!(out.shape() == Shape{s.n, 1, s.h, s.w})) out.resize({s.n, 1, s.h, s.w});
  for (int n = 0; n < s.n; ++n) std::copy(in.channel(n, c), in.channel(n, c) + s.plane(), out.image(n));
}

// d_pred[:, c] = weight * g
void put_channel(Tensor& d_pred, const Tensor& g, int c, float weight) {
  const Shape s = d_pred.shape();
  for (int n = 0; n < s.n; ++n) {
    const float* src = g.image(n);
    float* dst = d_pred.channel(n, c);
    for (std::size_t i = 0; i < s.plane(); ++i) dst[i] = weight * src[i];
  }
}

void add_channel(Tensor& d_pred, const Tensor& g, int c, float weight) {
  const Shape s = d_pred.shape();
  for (int n = 0; n < s.n; ++n) {
    const float* src = g.image(n);
    float* dst = d_pred.channel(n, c);
    for (std::size_t i = 0; i < s.plane(); ++i) dst[i] += weight * src[i];
  }
}

}  // namespace

HeadsLoss heads_loss(const std::vector<HeadKind>& heads, const Tensor& pred, const std::vector<HeadTarget>& targets,
                     Tensor* d_pred, const HeadsLossConfig& config) {
  const int k = static_cast<int>(heads.size());
  if (k == 0) throw Error("heads_loss: heads: expected at least one head");
  check_heads(heads, k, "heads_loss: heads");
  if (pred.shape().c != k)
    throw Error("heads_loss: pred: expected " + std::to_string(k) + " channels (one per head), got shape " + pred.shape().str());
  if (static_cast<int>(targets.size()) != k)
    throw Error("heads_loss: targets: expected " + std::to_string(k) + " (one per head), got " + std::to_string(targets.size()));
  for (int h = 0; h < k; ++h)
    if (!targets[h].target || !targets[h].mask || !std::isfinite(targets[h].weight) || targets[h].weight < 0)
      throw Error("heads_loss: targets[" + std::to_string(h) + "] (" + head_name(heads[h]) +
                  "): expected a target, a mask and a finite weight >= 0");
  if (d_pred && !(d_pred->shape() == pred.shape())) d_pred->resize(pred.shape());

  HeadsLoss out;
  Tensor mean, own, g_mean, g_own;
  copy_channel(mean, pred, 0);
  for (int h = 0; h < k; ++h) {
    const HeadTarget& t = targets[h];
    Tensor* g = d_pred ? &g_own : nullptr;
    LossParts parts;
    switch (heads[h]) {
      case HeadKind::mean:
        parts = masked_mse(mean, *t.target, *t.mask, g, t.denominator);
        break;
      case HeadKind::return_logit:
      case HeadKind::zero_logit:
        copy_channel(own, pred, h);
        parts = masked_bce_logits(own, *t.target, *t.mask, g, t.denominator);
        break;
      case HeadKind::log_scale_gaussian:
      case HeadKind::log_scale_laplace: {
        copy_channel(own, pred, h);
        const Spread family = heads[h] == HeadKind::log_scale_gaussian ? Spread::gaussian : Spread::laplace;
        Tensor* gm = d_pred && config.spread_trains_mean ? &g_mean : nullptr;
        parts = masked_nll(family, mean, own, *t.target, *t.mask, gm, g, t.denominator, config.clamp);
        break;
      }
      case HeadKind::count:
        throw Error("heads_loss: heads: unknown head kind");
    }
    if (d_pred) put_channel(*d_pred, g_own, h, t.weight);
    out.per_head.push_back(parts);
    out.total += t.weight * parts.data;
    // The spread's gradient to the mean, added after the mean head's own (channel 0 was written).
    if (d_pred && config.spread_trains_mean && (heads[h] == HeadKind::log_scale_gaussian || heads[h] == HeadKind::log_scale_laplace))
      add_channel(*d_pred, g_mean, 0, t.weight);
  }
  return out;
}

void sigmoid_forward(Tensor& out, const Tensor& in) {
  if (&out != &in && !(out.shape() == in.shape())) out.resize(in.shape());
  const float* x = in.data();
  float* y = out.data();
  for (std::size_t i = 0; i < in.numel(); ++i) {
    const float e = std::exp(-std::abs(x[i]));  // in (0, 1]: no overflow for any input
    y[i] = x[i] >= 0 ? 1.f / (1.f + e) : e / (1.f + e);
  }
}

int head_channel(const std::vector<HeadKind>& heads, HeadKind kind) {
  const auto it = std::find(heads.begin(), heads.end(), kind);
  return it == heads.end() ? -1 : static_cast<int>(it - heads.begin());
}

void zero_indicator(Tensor& out, const Tensor& target) {
  if (!(out.shape() == target.shape())) out.resize(target.shape());
  for (std::size_t i = 0; i < target.numel(); ++i) out.data()[i] = target.data()[i] <= 0.f ? 1.f : 0.f;
}

double logit_probability(double z) {
  const double e = std::exp(-std::abs(z));
  return z >= 0 ? 1 / (1 + e) : e / (1 + e);
}

double nonzero_center(double mean, double p_zero) { return mean / (1 - std::clamp(p_zero, 0.0, 0.9)); }

bool has_spread_head(const std::vector<HeadKind>& heads) {
  return std::any_of(heads.begin(), heads.end(),
                     [](HeadKind h) { return h == HeadKind::log_scale_gaussian || h == HeadKind::log_scale_laplace; });
}

void heads_output_transform(Tensor& y, const std::vector<HeadKind>& heads, LogScaleClamp clamp, float spread_scale) {
  if (heads.empty()) return;
  const Shape s = y.shape();
  if (s.c != static_cast<int>(heads.size()))
    throw Error("heads_output_transform: y: expected " + std::to_string(heads.size()) + " channels, got shape " + s.str());
  for (int n = 0; n < s.n; ++n)
    for (int c = 0; c < s.c; ++c) {
      float* v = y.channel(n, c);
      if (heads[c] == HeadKind::return_logit || heads[c] == HeadKind::zero_logit)
        for (std::size_t i = 0; i < s.plane(); ++i) {
          const float e = std::exp(-std::abs(v[i]));
          v[i] = v[i] >= 0 ? 1.f / (1.f + e) : e / (1.f + e);
        }
      else if (heads[c] == HeadKind::log_scale_gaussian || heads[c] == HeadKind::log_scale_laplace)
        for (std::size_t i = 0; i < s.plane(); ++i) v[i] = spread_scale * std::exp(std::clamp(v[i], clamp.min, clamp.max));
    }
}

double SpreadResidual::quantile(double mean, double u) const {
  const int bin = static_cast<int>(std::upper_bound(mean_edges.begin(), mean_edges.end(), mean) - mean_edges.begin());
  const float* q = z.data() + static_cast<std::size_t>(bin) * static_cast<std::size_t>(levels);
  const double x = u * levels - 0.5;  // table point k sits at probability (k + 0.5) / levels
  if (x <= 0) return q[0];
  if (x >= levels - 1) return q[levels - 1];
  const int k = static_cast<int>(x);
  return q[k] + (x - k) * (q[k + 1] - q[k]);
}

void check_spread_residual(const SpreadResidual& r, const std::string& where) {
  if (r.empty()) {
    if (!r.mean_edges.empty() || !r.z.empty() || r.target_step != 0.f)
      throw Error(where + ": levels 0 (no table) but edges, quantiles or a step are given");
    return;
  }
  if (r.levels < 2 || r.levels > 4096) throw Error(where + ": levels: expected 2 .. 4096, got " + std::to_string(r.levels));
  if (r.mean_edges.size() > 4096) throw Error(where + ": mean_edges: more than 4096");
  for (std::size_t i = 0; i < r.mean_edges.size(); ++i)
    if (!std::isfinite(r.mean_edges[i]) || (i > 0 && r.mean_edges[i] < r.mean_edges[i - 1]))
      throw Error(where + ": mean_edges: expected finite ascending numbers (at " + std::to_string(i) + ")");
  const std::size_t want = static_cast<std::size_t>(r.bins()) * static_cast<std::size_t>(r.levels);
  if (r.z.size() != want)
    throw Error(where + ": z: expected bins x levels = " + std::to_string(want) + " values, got " + std::to_string(r.z.size()));
  for (std::size_t i = 0; i < r.z.size(); ++i)
    if (!std::isfinite(r.z[i]) || (i % static_cast<std::size_t>(r.levels) > 0 && r.z[i] < r.z[i - 1]))
      throw Error(where + ": z: expected finite values, non-decreasing within each bin (at " + std::to_string(i) + ")");
  if (!(r.target_step >= 0) || !std::isfinite(r.target_step))
    throw Error(where + ": target_step: expected a finite number >= 0, got " + std::to_string(r.target_step));
}

std::string spread_residual_json(const SpreadResidual& r) {
  return nlohmann::json{{"levels", r.levels}, {"mean_edges", r.mean_edges}, {"z", r.z}, {"target_step", r.target_step}}.dump();
}

SpreadResidual parse_spread_residual(const std::string& json, const std::string& where) {
  SpreadResidual r;
  try {
    const nlohmann::json j = nlohmann::json::parse(json);
    r.levels = j.at("levels").get<int>();
    r.mean_edges = j.at("mean_edges").get<std::vector<float>>();
    r.z = j.at("z").get<std::vector<float>>();
    r.target_step = j.at("target_step").get<float>();
  } catch (const nlohmann::json::exception& e) {
    throw Error(where + ": not a spread residual table (" + e.what() + ")");
  }
  check_spread_residual(r, where);
  return r;
}

}  // namespace lidarsim::nn
