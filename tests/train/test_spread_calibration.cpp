// The spread head's calibration (train/spread_metrics.h calibrate_spread): on cells whose residuals
// are wider than the predicted scale (what a mean that fits its own training cells better than new
// ones gives), the factor fitted on one group of cells makes the central 50 % and 90 % intervals of
// another group hold about 50 % and 90 %, where the uncalibrated ones hold far less.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

#include "common/error.h"
#include "data/dataset.h"
#include "data/frame_source.h"
#include "data/split.h"
#include "nn/heads.h"
#include "nn/unet.h"
#include "pgm/encoder.h"
#include "train/spread_metrics.h"

using namespace lidarsim;

namespace {

constexpr int kCalibRows = 16, kCalibCols = 256;
constexpr double kWider = 1.8;  // true scale / predicted scale on new cells

// A zero-centred draw of the family with scale 1.
double unit_draw(nn::HeadKind spread, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(1e-12, 1.0 - 1e-12);
  if (spread == nn::HeadKind::log_scale_laplace) {
    const double d = u(rng) - 0.5;
    return -(d < 0 ? -1.0 : 1.0) * std::log(1 - 2 * std::abs(d));
  }
  return std::normal_distribution<double>(0.0, 1.0)(rng);
}

// One frame: predicted log-scales that vary per cell (0.01 .. 0.1), residuals drawn with kWider
// times the predicted scale. Columns < kCols / 2 have role 1 (calibration), the others role 2.
struct Frame {
  std::vector<float> mean, log_scale, target, mask;
  std::vector<std::uint8_t> roles;
};
Frame frame(nn::HeadKind spread, std::uint64_t seed) {
  Frame f;
  const std::size_t plane = static_cast<std::size_t>(kCalibRows) * kCalibCols;
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> log_b(std::log(0.01), std::log(0.1));
  for (std::size_t i = 0; i < plane; ++i) {
    const double s = log_b(rng);
    f.mean.push_back(0.4f);
    f.log_scale.push_back(static_cast<float>(s));
    f.target.push_back(static_cast<float>(0.4 + kWider * std::exp(s) * unit_draw(spread, rng)));
    f.mask.push_back(i % 7 != 0 ? 1.f : 0.f);
  }
  for (int c = 0; c < kCalibCols; ++c) f.roles.push_back(c < kCalibCols / 2 ? 1 : 2);
  return f;
}

train::SpreadMetrics measure(const Frame& f, nn::HeadKind spread, std::uint8_t role, double factor) {
  train::SpreadSums sums;
  train::add_spread_cells(sums, spread, f.mean.data(), f.log_scale.data(), f.target.data(), f.mask.data(), f.roles,
                          kCalibRows, kCalibCols, role, {}, factor);
  return sums.get();
}

}  // namespace

// Truth known: residuals kWider x the predicted scale. Uncalibrated, the 50 % / 90 % intervals
// hold ~0.32 / ~0.72 (Laplace) or ~0.29 / ~0.64 (Gaussian); with the factor fitted on the other
// half of the columns, 0.50 / 0.90 within 0.02 (1,755 cells each; the draws are fixed by the
// seed), and the NLL drops.
TEST(SpreadCalibration, CalibratedIntervalsCoverTheirProbabilityOnNewCells) {
  for (nn::HeadKind spread : {nn::HeadKind::log_scale_laplace, nn::HeadKind::log_scale_gaussian}) {
    SCOPED_TRACE(nn::head_name(spread));
    const Frame f = frame(spread, 11);
    const double factor = measure(f, spread, 1, 1.0).mle_factor;
    EXPECT_NEAR(factor, kWider, 0.06 * kWider);
    const train::SpreadMetrics raw = measure(f, spread, 2, 1.0), calibrated = measure(f, spread, 2, factor);
    EXPECT_LT(raw.within50, 0.40);
    EXPECT_LT(raw.within90, 0.80);
    EXPECT_NEAR(calibrated.within50, 0.5, 0.02);
    EXPECT_NEAR(calibrated.within90, 0.9, 0.02);
    EXPECT_LT(calibrated.nll, raw.nll - 0.1);
    // Already calibrated: the best factor is 1.
    EXPECT_NEAR(measure(f, spread, 2, factor).mle_factor, 1.0, 0.06);
  }
}

// Through a model: a UNet whose outputs are its head biases (every weight zero) predicts mean 0.4
// and a scale kWider times too narrow. calibrate_spread fits the factor on the calibration columns
// alone (the other columns' targets, made wild, do not move it), stores it in the model's config,
// and validate_spread then measures calibrated coverage on the other columns.
TEST(SpreadCalibration, CalibrateSpreadFitsTheFactorOnItsRegionAloneAndTheModelCarriesIt) {
  const double b = 0.05;
  data::Dataset d;
  d.channels = {"range", "class"};
  d.layout = pgm::BeamLayout::uniform(kCalibRows, 1.0, -8.0, kCalibCols);
  d.pgm.resize({2, 2, kCalibRows, kCalibCols});
  d.target.resize({2, 1, kCalibRows, kCalibCols});
  d.mask.resize({2, 1, kCalibRows, kCalibCols});
  std::mt19937_64 rng(5);
  for (int n = 0; n < 2; ++n) {
    d.frames.push_back("calib/" + std::to_string(n));
    d.row_modes.push_back("firing_order");
    for (int r = 0; r < kCalibRows; ++r)
      for (int c = 0; c < kCalibCols; ++c) {
        d.pgm.at(n, 0, r, c) = 10.f;
        d.pgm.at(n, 1, r, c) = static_cast<float>(pgm::cls::road);
        d.target.at(n, 0, r, c) = static_cast<float>(0.4 + kWider * b * unit_draw(nn::HeadKind::log_scale_laplace, rng));
        d.mask.at(n, 0, r, c) = 1.f;
      }
  }
  pgm::EncoderConfig encoder;
  encoder.channels = {"range", "class"};
  nn::UNetConfig arch{encoder.input_channels(), 2, 4, 1};
  arch.heads = {nn::HeadKind::mean, nn::HeadKind::log_scale_laplace};
  nn::UNet model(arch);
  std::fill(model.params().values(), model.params().values() + model.params().size(), 0.f);
  float* bias = model.params().value(model.params().find("head/bias"));
  bias[0] = 0.4f, bias[1] = static_cast<float>(std::log(b));
  // Calibration = the first half of the columns; scored = the second half (as two sector splits).
  data::SectorSplit calib, scored;
  calib.regions = {{0.0, 0.5}};
  scored.regions = {{0.5, 1.0}};
  calib.guard_columns = scored.guard_columns = 0;
  ASSERT_EQ(calib.roles(kCalibCols)[0], data::kValidation);
  ASSERT_EQ(calib.roles(kCalibCols)[kCalibCols - 1], data::kTrain);
  const auto source = data::memory_frame_source(d, "calib");
  const train::SpreadMetrics raw = train::validate_spread(model, encoder, {source.get()}, scored);
  const train::SpreadMetrics before = train::calibrate_spread(model, encoder, {source.get()}, calib);
  EXPECT_NEAR(before.within50, raw.within50, 0.03);  // same truth on both halves
  EXPECT_NEAR(model.config().spread_scale, kWider, 0.06 * kWider);
  const train::SpreadMetrics after = train::validate_spread(model, encoder, {source.get()}, scored);
  EXPECT_LT(raw.within50, 0.40);
  EXPECT_NEAR(after.within50, 0.5, 0.03);
  EXPECT_NEAR(after.within90, 0.9, 0.02);

  // The scored cells never enter the fit: wild targets there leave the factor as it was.
  data::Dataset wild = d;
  for (int n = 0; n < 2; ++n)
    for (int r = 0; r < kCalibRows; ++r)
      for (int c = kCalibCols / 2; c < kCalibCols; ++c) wild.target.at(n, 0, r, c) = 5.f;
  nn::UNet again(arch);
  std::copy(model.params().values(), model.params().values() + model.params().size(), again.params().values());
  const auto wild_source = data::memory_frame_source(wild, "wild");
  train::calibrate_spread(again, encoder, {wild_source.get()}, calib);
  EXPECT_EQ(again.config().spread_scale, model.config().spread_scale);
  // A model without a spread head has no factor to carry.
  nn::UNet plain(nn::UNetConfig{encoder.input_channels(), 1, 4, 1});
  EXPECT_THROW(plain.set_spread_scale(1.5f), Error);
}

// The residual table (train/spread_metrics.h spread_residual_from) on cells with known truth: the
// standardised residual is skewed (exponential - 1) where the mean is below 0.3 and uniform on
// [-0.8, 0.8] above it; targets are reported on a 0.01 grid. The table's bins split the means
// into equal counts, each bin's quantiles are the truth's within 0.08 (the grid's rounding is
// 0.005 / 0.1 = 0.05 of a scale at most, 20,000 cells a bin leave ~0.02 of sampling error), and the grid step is found: 0.01, or 0 for targets off a
// grid. A Laplace (the head's own shape) is 0.3 away at the 10 % quantile of the low bins.
TEST(SpreadResidual, TableRecoversAShapeThatDependsOnTheMeanAndTheTargetsGrid) {
  std::mt19937_64 rng(21);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const auto low = [](double p) { return -std::log(1 - p) - 1; };
  const auto high = [](double p) { return 0.8 * (2 * p - 1); };
  std::vector<double> mean, z, y, y_continuous;
  for (int i = 0; i < 160000; ++i) {
    const double m = 0.1 + 0.4 * u(rng), scale = 0.1;
    const double truth = m < 0.3 ? low(u(rng)) : high(u(rng));
    const double reported = std::round((m + scale * truth) * 100) / 100;
    mean.push_back(m);
    y.push_back(reported);
    z.push_back((reported - m) / scale);
    y_continuous.push_back(m + scale * truth);
  }
  const nn::SpreadResidual r = train::spread_residual_from(mean, z, y, 8, 64);
  ASSERT_EQ(r.bins(), 8);
  EXPECT_NEAR(r.mean_edges[3], 0.3, 0.01);  // the median of U(0.1, 0.5)
  EXPECT_NEAR(r.target_step, 0.01, 1e-6);
  for (double m : {0.12, 0.2, 0.28, 0.32, 0.4, 0.48})
    for (double p : {0.1, 0.25, 0.5, 0.75, 0.9})
      EXPECT_NEAR(r.quantile(m, p), m < 0.3 ? low(p) : high(p), 0.08) << "mean " << m << " p " << p;
  EXPECT_GT(std::abs(r.quantile(0.2, 0.1) - std::log(0.2)), 0.3);  // Laplace(0, 1) at 0.1: log 0.2
  EXPECT_EQ(train::target_grid_step(y_continuous), 0.0);
  std::vector<double> eight_bit;
  for (int i = 0; i < 1000; ++i) eight_bit.push_back(static_cast<float>((i * 37 % 256) / 255.0));
  EXPECT_NEAR(train::target_grid_step(eight_bit), 1 / 255.0, 1e-7);
  EXPECT_THROW(train::spread_residual_from({0.1, 0.2}, {0, 1}, {0.1, 0.2}, 8, 64), Error);
}
