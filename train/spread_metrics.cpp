#include "train/spread_metrics.h"

#include <algorithm>
#include <cmath>

#include "common/error.h"

namespace lidarsim::train {

namespace {

// Every frame of `sets` through the model, one at a time: `visit(frame, prediction planes, the
// split's role per column, rows, cols)`.
template <class Visit>
void for_each_prediction(nn::UNet& model, const pgm::EncoderConfig& encoder,
                         const std::vector<const data::FrameSource*>& sets, const data::SectorSplit& split,
                         Visit&& visit) {
  nn::Tensor input, prediction;
  for (const data::FrameSource* set : sets)
    for (int n = 0; n < set->size(); ++n) {
      const data::FrameRef frame = set->frame(n);
      input.resize({1, encoder.input_channels(), set->rows(), set->cols()});
      pgm::encode_input(set->view(frame), encoder, input, 0);
      model.predict(input, prediction);
      const auto& ids = set->header().frames;
      const auto roles = split.roles(set->cols(), n < static_cast<int>(ids.size()) ? ids[static_cast<std::size_t>(n)] : "");
      visit(frame, prediction.data(), roles, set->rows(), set->cols());
    }
}

}  // namespace

SpreadMetrics SpreadSums::get() const {
  SpreadMetrics m;
  m.cells = cells;
  if (cells > 0) {
    m.nll = nll / cells;
    m.within50 = static_cast<double>(within50) / cells;
    m.within90 = static_cast<double>(within90) / cells;
    m.mle_factor = squared ? std::sqrt(ratio / cells) : ratio / cells;
  }
  return m;
}

double central_half_width(nn::HeadKind spread, double p) {
  if (spread == nn::HeadKind::log_scale_laplace) return -std::log(1 - p);
  if (spread != nn::HeadKind::log_scale_gaussian) throw Error("central_half_width: not a spread head");
  // Normal quantile of (1 + p) / 2 by bisection on erf (no table, exact to float precision).
  double lo = 0, hi = 10;
  for (int i = 0; i < 80; ++i) {
    const double mid = 0.5 * (lo + hi);
    (std::erf(mid / std::sqrt(2.0)) < p ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

void add_spread_cells(SpreadSums& sums, nn::HeadKind spread, const float* mean, const float* log_scale,
                      const float* target, const float* mask, const std::vector<std::uint8_t>& roles, int rows,
                      int cols, std::uint8_t want_role, nn::LogScaleClamp clamp, double scale_factor) {
  const bool laplace = spread == nn::HeadKind::log_scale_laplace;
  sums.squared = !laplace;
  const double w50 = central_half_width(spread, 0.5), w90 = central_half_width(spread, 0.9);
  const double constant = laplace ? std::log(2.0) : 0.5 * std::log(2 * M_PI);
  const std::size_t plane = static_cast<std::size_t>(rows) * cols;
  for (std::size_t i = 0; i < plane; ++i) {
    if (mask[i] <= 0 || roles[i % static_cast<std::size_t>(cols)] != want_role) continue;
    const double s = std::clamp(log_scale[i], clamp.min, clamp.max) + std::log(scale_factor);
    const double scale = std::exp(s);
    const double r = std::abs(static_cast<double>(target[i]) - mean[i]) / scale;
    sums.nll += s + (laplace ? r : 0.5 * r * r) + constant;
    sums.ratio += laplace ? r : r * r;
    sums.within50 += r <= w50;
    sums.within90 += r <= w90;
    ++sums.cells;
  }
}

SpreadMetrics validate_spread(nn::UNet& model, const pgm::EncoderConfig& encoder,
                              const std::vector<const data::FrameSource*>& sets, const data::SectorSplit& split) {
  const auto& heads = model.config().heads;
  if (heads.size() < 2) throw Error("validate_spread: the model has no spread head");
  SpreadSums sums;
  const int zc = nn::head_channel(heads, nn::HeadKind::zero_logit);
  double p0 = 0, zeros = 0, cells = 0;
  for_each_prediction(model, encoder, sets, split,
                      [&](const data::FrameRef& frame, const float* pred, const std::vector<std::uint8_t>& roles, int rows,
                          int cols) {
                        const std::size_t plane = static_cast<std::size_t>(rows) * cols;
                        add_spread_cells(sums, heads[1], pred, pred + plane, frame.target, frame.mask, roles, rows,
                                         cols, data::kValidation, {}, model.config().spread_scale);
                        if (zc < 0) return;
                        for (std::size_t i = 0; i < plane; ++i)
                          if (frame.mask[i] > 0 && roles[i % static_cast<std::size_t>(cols)] == data::kValidation) {
                            p0 += nn::logit_probability(pred[static_cast<std::size_t>(zc) * plane + i]);
                            zeros += frame.target[i] <= 0, cells += 1;
                          }
                      });
  SpreadMetrics m = sums.get();
  if (zc >= 0 && cells > 0) m.zero_predicted = p0 / cells, m.zero_measured = zeros / cells;
  return m;
}

SpreadMetrics calibrate_spread(nn::UNet& model, const pgm::EncoderConfig& encoder,
                               const std::vector<const data::FrameSource*>& sets, const data::SectorSplit& region) {
  const SpreadMetrics before = validate_spread(model, encoder, sets, region);
  if (before.cells == 0) throw Error("calibrate_spread: the calibration region has no cell with a return");
  model.set_spread_scale(static_cast<float>(model.config().spread_scale * before.mle_factor));
  return before;
}

namespace {

// Linear interpolation between order statistics of sorted `s` at probability q.
double percentile_of_sorted(const std::vector<double>& s, double q) {
  const double x = q * static_cast<double>(s.size() - 1);
  const std::size_t k = std::min(static_cast<std::size_t>(x), s.size() - 1), k1 = std::min(k + 1, s.size() - 1);
  return s[k] + (x - static_cast<double>(k)) * (s[k1] - s[k]);
}

}  // namespace

double target_grid_step(std::vector<double> targets) {
  if (targets.size() < 100) return 0;
  std::sort(targets.begin(), targets.end());
  targets.erase(std::unique(targets.begin(), targets.end(), [](double a, double b) { return b - a < 1e-7; }), targets.end());
  if (targets.size() < 2) return 0;
  double gap = targets.back() - targets.front();
  for (std::size_t i = 1; i < targets.size(); ++i) gap = std::min(gap, targets[i] - targets[i - 1]);
  // Over the span the step's float error averages out: KITTI's 0.0099999905 becomes 0.01.
  const double span = targets.back() - targets.front();
  const double step = span / std::round(span / gap);
  for (double v : targets)
    if (std::abs(v / step - std::round(v / step)) > 0.01) return 0;
  return step;
}

nn::SpreadResidual spread_residual_from(const std::vector<double>& mean, const std::vector<double>& z,
                                        const std::vector<double>& y, int bins, int levels) {
  if (mean.size() != z.size() || mean.size() != y.size()) throw Error("spread_residual_from: sizes differ");
  if (bins < 1 || levels < 2) throw Error("spread_residual_from: bins >= 1 and levels >= 2");
  if (mean.size() < static_cast<std::size_t>(20 * bins))
    throw Error("spread_residual_from: " + std::to_string(mean.size()) + " cells, fewer than 20 per bin of the mean (" +
                std::to_string(bins) + " bins)");
  nn::SpreadResidual r;
  r.levels = levels;
  std::vector<double> sorted_mean = mean;
  std::sort(sorted_mean.begin(), sorted_mean.end());
  for (int b = 1; b < bins; ++b) r.mean_edges.push_back(static_cast<float>(percentile_of_sorted(sorted_mean, double(b) / bins)));
  std::vector<std::vector<double>> by_bin(static_cast<std::size_t>(bins));
  for (std::size_t i = 0; i < mean.size(); ++i) {
    // The same rule as SpreadResidual::quantile (upper_bound on the float edges).
    const auto bin = std::upper_bound(r.mean_edges.begin(), r.mean_edges.end(), static_cast<float>(mean[i])) - r.mean_edges.begin();
    by_bin[static_cast<std::size_t>(bin)].push_back(z[i]);
  }
  for (auto& v : by_bin) {
    // Ties in the mean can leave a bin empty: it takes every cell's residual.
    if (v.empty()) v = z;
    std::sort(v.begin(), v.end());
    for (int k = 0; k < levels; ++k) r.z.push_back(static_cast<float>(percentile_of_sorted(v, (k + 0.5) / levels)));
  }
  r.target_step = static_cast<float>(target_grid_step(y));
  nn::check_spread_residual(r, "spread_residual_from");
  return r;
}

nn::SpreadResidual fit_spread_residual(nn::UNet& model, const pgm::EncoderConfig& encoder,
                                       const std::vector<const data::FrameSource*>& sets,
                                       const data::SectorSplit& region, int bins, int levels) {
  const auto& heads = model.config().heads;
  if (heads.size() < 2 || !nn::has_spread_head(heads)) throw Error("fit_spread_residual: the model has no spread head");
  const nn::LogScaleClamp clamp{};
  // With a zero head the table describes the cells that are not 0, around their centre.
  const int zc = nn::head_channel(heads, nn::HeadKind::zero_logit);
  std::vector<double> mean, z, y;
  for_each_prediction(model, encoder, sets, region,
                      [&](const data::FrameRef& frame, const float* mu, const std::vector<std::uint8_t>& roles, int rows,
                          int cols) {
                        const std::size_t plane = static_cast<std::size_t>(rows) * cols;
                        const float* log_scale = mu + plane;
                        for (std::size_t i = 0; i < plane; ++i) {
                          if (frame.mask[i] <= 0 || roles[i % static_cast<std::size_t>(cols)] != data::kValidation)
                            continue;
                          if (zc >= 0 && frame.target[i] <= 0) continue;
                          const double scale =
                              model.config().spread_scale * std::exp(std::clamp(log_scale[i], clamp.min, clamp.max));
                          const double centre =
                              zc < 0 ? mu[i]
                                     : nn::nonzero_center(mu[i], nn::logit_probability(mu[static_cast<std::size_t>(zc) * plane + i]));
                          mean.push_back(centre);
                          z.push_back((frame.target[i] - centre) / scale);
                          y.push_back(frame.target[i]);
                        }
                      });
  nn::SpreadResidual r = spread_residual_from(mean, z, y, bins, levels);
  model.set_spread_residual(r);
  return r;
}

}  // namespace lidarsim::train
