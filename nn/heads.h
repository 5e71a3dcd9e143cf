#pragma once
// Output heads: what each output channel of a several-output UNet predicts, the loss each is
// trained with, and the transform that turns it into its value at inference.
//   mean                the paper's regression output, masked MSE (nn/loss.h masked_mse)
//   return_logit        logit of a probability (e.g. that a beam returns), masked BCE on logits;
//                       at inference sigmoid(z)
//   log_scale_gaussian  log sigma of a Gaussian around the mean head, masked Gaussian NLL;
//                       at inference sigma = exp(clamp(s))
//   log_scale_laplace   log b of a Laplace around the mean head, masked Laplace NLL;
//                       at inference b = exp(clamp(s))
//   zero_logit          logit of P(target == 0) (a sensor's zero intensity readings), masked BCE
//                       on logits against the indicator (target <= 0); at inference sigmoid(z)
// Rules (check_heads): channel 0 is the mean (a lookup base is added to it); every other kind
// appears at most once, at most one of the two spread kinds, and zero_logit only with a spread
// (a draw is 0 with its probability, else from the spread: infer/intensity_sampling.h).
#include <array>
#include <string>
#include <vector>

#include "nn/loss.h"
#include "nn/tensor.h"

namespace lidarsim::nn {

enum class HeadKind { mean, return_logit, log_scale_gaussian, log_scale_laplace, zero_logit, count };
inline constexpr std::array<const char*, 5> kHeadNames = {"mean", "return_logit", "log_scale_gaussian",
                                                          "log_scale_laplace", "zero_logit"};
static_assert(kHeadNames.size() == static_cast<std::size_t>(HeadKind::count), "one name per head kind");

const char* head_name(HeadKind kind);
// "mean,return_logit" <-> the kinds; `where` names the field in errors.
std::string heads_text(const std::vector<HeadKind>& heads);
std::vector<HeadKind> parse_heads(const std::string& text, const std::string& where);
// Throws an Error naming `where` when the heads break the rules above or their count is not
// out_channels. Empty heads are always valid (every channel a plain output, the mean's loss).
void check_heads(const std::vector<HeadKind>& heads, int out_channels, const std::string& where);

// One head's cells: target and mask [N, 1, H, W] (the spread heads' target is the mean head's
// target: the measured value), its loss weight, and the denominator (nn/loss.h: 0 = this batch's
// own count of masked-in cells; data-parallel training passes the count over all processes).
struct HeadTarget {
  const Tensor* target = nullptr;
  const Tensor* mask = nullptr;
  float weight = 1.f;
  long denominator = 0;
};
struct HeadsLossConfig {
  LogScaleClamp clamp{};
  // false: the spread heads' NLL passes no gradient to the mean channel (the mean stays the
  // paper's masked-MSE mean; its MAE is not traded for the spread's likelihood).
  bool spread_trains_mean = false;
};
struct HeadsLoss {
  std::vector<LossParts> per_head;  // unweighted, one per head
  double total = 0;                 // sum of weight * data over heads
};

// pred [N, K, H, W] with K = heads.size(); targets one per head. Writes d_pred (=) [N, K, H, W]
// when given: the weighted sum's gradient. No L2 term (add l2_penalty once).
HeadsLoss heads_loss(const std::vector<HeadKind>& heads, const Tensor& pred, const std::vector<HeadTarget>& targets,
                     Tensor* d_pred, const HeadsLossConfig& config = {});

// True when one of the heads is log_scale_gaussian or log_scale_laplace.
bool has_spread_head(const std::vector<HeadKind>& heads);
// The channel of head `kind`, -1 when absent.
int head_channel(const std::vector<HeadKind>& heads, HeadKind kind);
// The zero head's target: 1 where target <= 0 (the sensor reported 0), else 0; shape of `target`.
void zero_indicator(Tensor& out, const Tensor& target);
// sigmoid(z), stable for any z (the zero and return heads' probability).
double logit_probability(double z);
// Where the draws that are not 0 are centred: for a target >= 0, E[y] = (1 - p0) E[y | y > 0], so
// the mean head's value divided by 1 - p0 (p0 capped at 0.9: no blow-up where the head is sure of
// a zero). The residual table of a model with a zero head is fitted around this centre on the
// cells that are not 0 (train/spread_metrics.h), and draws use the same centre.
double nonzero_center(double mean, double p_zero);

// Numerically stable logistic function, elementwise: in and out any shape (out may be in).
void sigmoid_forward(Tensor& out, const Tensor& in);
// Inference: in place on y [N, K, H, W], return_logit and zero_logit channels become probabilities and log-scale
// channels scales (spread_scale * exp of the clamped log-scale: UNetConfig::spread_scale, the
// calibration factor); mean channels stay.
void heads_output_transform(Tensor& y, const std::vector<HeadKind>& heads, LogScaleClamp clamp = {},
                            float spread_scale = 1.f);

// The spread head's standardised residual z = (y - mean) / scale as an empirical distribution,
// fitted after training on cells the mean never trained on (train/spread_metrics.h
// fit_spread_residual), used instead of the Laplace/Gaussian shape when drawing. The residual's
// shape depends on where the mean lies (near the bottom of the range measured values split into
// zeros and a bulk; at the common levels they are tight), so there is one table per bin of the
// predicted mean: `levels` quantiles of z at probabilities (k + 0.5) / levels, bins split at
// `mean_edges` (ascending, bins = edges + 1). `target_step`: the grid the measured targets sit on
// (KITTI reflectance 0.01, 8-bit sensors 1/255), draws are rounded to it; 0 = continuous.
struct SpreadResidual {
  int levels = 0;                  // 0: none (draw from the head's parametric shape)
  std::vector<float> mean_edges;   // [bins - 1]
  std::vector<float> z;            // [bins][levels], non-decreasing within a bin
  float target_step = 0.f;
  bool empty() const { return levels == 0; }
  int bins() const { return static_cast<int>(mean_edges.size()) + 1; }
  // z at probability u in (0, 1) for a cell whose predicted mean is `mean`: linear between the
  // table's points, its end points beyond them.
  double quantile(double mean, double u) const;
  bool operator==(const SpreadResidual&) const = default;
};
// Throws an Error naming `where` unless the table is empty or well formed (levels 2..4096, finite
// sorted edges, finite z non-decreasing within each bin, step finite and >= 0).
void check_spread_residual(const SpreadResidual& r, const std::string& where);
// As stored in checkpoints: {"levels": K, "mean_edges": [...], "z": [...], "target_step": s}.
// Parsing checks the table (errors name `where`).
std::string spread_residual_json(const SpreadResidual& r);
SpreadResidual parse_spread_residual(const std::string& json, const std::string& where);

}  // namespace lidarsim::nn
