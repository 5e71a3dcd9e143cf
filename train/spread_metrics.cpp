#include "train/spread_metrics.h"

#include <algorithm>
#include <cmath>

#include "common/error.h"

namespace lidarsim::train {

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
  nn::Tensor input, prediction;
  for (const data::FrameSource* set : sets)
    for (int n = 0; n < set->size(); ++n) {
      const data::FrameRef frame = set->frame(n);
      input.resize({1, encoder.input_channels(), set->rows(), set->cols()});
      pgm::encode_input(set->view(frame), encoder, input, 0);
      model.predict(input, prediction);
      const auto& ids = set->header().frames;
      const auto roles = split.roles(set->cols(), n < static_cast<int>(ids.size()) ? ids[static_cast<std::size_t>(n)] : "");
      const std::size_t plane = static_cast<std::size_t>(set->rows()) * set->cols();
      add_spread_cells(sums, heads[1], prediction.data(), prediction.data() + plane, frame.target, frame.mask, roles,
                       set->rows(), set->cols(), data::kValidation, {}, model.config().spread_scale);
    }
  return sums.get();
}

SpreadMetrics calibrate_spread(nn::UNet& model, const pgm::EncoderConfig& encoder,
                               const std::vector<const data::FrameSource*>& sets, const data::SectorSplit& region) {
  const SpreadMetrics before = validate_spread(model, encoder, sets, region);
  if (before.cells == 0) throw Error("calibrate_spread: the calibration region has no cell with a return");
  model.set_spread_scale(static_cast<float>(model.config().spread_scale * before.mle_factor));
  return before;
}

}  // namespace lidarsim::train
