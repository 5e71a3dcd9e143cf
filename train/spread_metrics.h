#pragma once
// Validation of a spread head (nn/heads.h log_scale_gaussian / log_scale_laplace): how well the
// predicted distribution around the mean describes the measured intensity on the scored cells.
//   nll       mean negative log-likelihood, nats per cell (nn/loss.h masked_nll's definition)
//   within50  share of cells with |y - mean| inside the central 50 % interval of the prediction
//   within90  the same for 90 % (a calibrated spread gives 0.5 and 0.9; lower: too narrow)
// The scale is the model's: exp(clamp(s)) times its calibration factor (UNetConfig::spread_scale).
#include <cstdint>
#include <vector>

#include "data/frame_source.h"
#include "data/split.h"
#include "nn/heads.h"
#include "nn/unet.h"
#include "pgm/encoder.h"
#include "train/trainer.h"

namespace lidarsim::train {

struct SpreadSums {
  double nll = 0;
  // Sum of |y - mean| / scale (Laplace) or (y - mean)^2 / scale^2 (Gaussian): the likelihood's
  // best factor of the scale follows from it (SpreadMetrics::mle_factor).
  double ratio = 0;
  bool squared = false;
  long within50 = 0, within90 = 0, cells = 0;
  SpreadMetrics get() const;
};

// Half-width of the central interval holding probability p of a distribution with scale 1
// (Gaussian sigma = 1: the normal quantile z_{(1+p)/2}; Laplace b = 1: -log(1 - p)).
double central_half_width(nn::HeadKind spread, double p);

// Adds one frame's cells (mask > 0 and roles[column] == want_role): mean and log_scale are the
// network's raw channels 0 and 1 [rows * cols]; the log-scale is clamped as in training, then the
// scale multiplied by `scale_factor` (the model's calibration, UNetConfig::spread_scale).
void add_spread_cells(SpreadSums& sums, nn::HeadKind spread, const float* mean, const float* log_scale,
                      const float* target, const float* mask, const std::vector<std::uint8_t>& roles, int rows,
                      int cols, std::uint8_t want_role = data::kValidation, nn::LogScaleClamp clamp = {},
                      double scale_factor = 1.0);

// The model's spread on the validation cells of `split` in `sets` (one frame at a time).
SpreadMetrics validate_spread(nn::UNet& model, const pgm::EncoderConfig& encoder,
                              const std::vector<const data::FrameSource*>& sets, const data::SectorSplit& split);

// Calibrates the spread on the validation cells of `region`, cells the mean never trained on
// (lidar-train: the --early-stop inner region, guarded from the training and the scored cells):
// multiplies the model's UNetConfig::spread_scale by the likelihood's best factor there. The
// head fits its scale to the training cells' residuals, which the mean fits better than cells it
// never saw, so its intervals are too narrow on new cells. Returns the region's metrics before.
SpreadMetrics calibrate_spread(nn::UNet& model, const pgm::EncoderConfig& encoder,
                               const std::vector<const data::FrameSource*>& sets, const data::SectorSplit& region);

// The grid the targets sit on (KITTI reflectance: 0.01; 8-bit intensity: 1/255): the smallest gap
// between distinct values, refined over their span, when every value lies on it within 1 % of a
// step; 0 (continuous) otherwise or with fewer than 100 values.
double target_grid_step(std::vector<double> targets);

// The residual table (nn::SpreadResidual) of cells with predicted mean `mean`, standardised
// residual `z` = (y - mean) / scale and target `y`: `bins` bins of the mean with equal cell counts,
// `levels` quantiles of z in each (at (k + 0.5) / levels, linear between order statistics), the
// targets' grid step. Throws when there are fewer than 20 cells per bin.
nn::SpreadResidual spread_residual_from(const std::vector<double>& mean, const std::vector<double>& z,
                                        const std::vector<double>& y, int bins = 8, int levels = 64);

// Fits that table on the validation cells of `region` (lidar-train: the --early-stop inner region,
// after calibrate_spread, with the calibrated scale) and stores it in the model
// (UNetConfig::spread_residual). Why there: the residuals of cells the mean trained on are smaller
// and shaped by the fit; on cells it never saw they are what a new place gets. With a zero head
// (nn/heads.h zero_logit) only cells with a target above 0 enter, around nn::nonzero_center (the
// zeros are drawn from the head). Returns the table.
nn::SpreadResidual fit_spread_residual(nn::UNet& model, const pgm::EncoderConfig& encoder,
                                       const std::vector<const data::FrameSource*>& sets,
                                       const data::SectorSplit& region, int bins = 8, int levels = 64);

}  // namespace lidarsim::train
