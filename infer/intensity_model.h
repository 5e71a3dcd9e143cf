#pragma once
// A trained intensity UNet ready for inference: the checkpoint's weights together with the input
// encoder and beam layout that travelled in its /config, so a Polar Grid Map is encoded exactly
// as in training. Shared by `lidar-infer predict` (recorded scans) and the simulation pipeline.
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "infer/intensity_sampling.h"
#include "nn/checkpoint.h"
#include "nn/unet.h"
#include "pgm/beam_layout.h"
#include "pgm/encoder.h"
#include "pgm/polar_grid_map.h"
#include "sensor/range_noise.h"

namespace lidarsim::infer {

class IntensityModel {
 public:
  // A lidar-train checkpoint (HDF5, nn/checkpoint.h) or a weights file (nn/checkpoint_weights.h),
  // told apart by content. Throws lidarsim::Error naming the file and what is wrong (missing,
  // torn, not a lidar-train checkpoint, shapes that do not match).
  static IntensityModel load(const std::filesystem::path& checkpoint);
  // A weights file only; unlike load(), links no HDF5 (intensity_model_load.cpp holds load()).
  static IntensityModel load_weights(const std::filesystem::path& weights);

  const pgm::EncoderConfig& encoder() const { return encoder_; }
  const pgm::BeamLayout& layout() const { return layout_; }
  const std::filesystem::path& path() const { return path_; }
  // PGM channels beyond pgm::kBaseChannels the encoder reads (to ask the projection for them).
  std::vector<std::string> extra_channels() const;

  // The checkpoint's spread head (log_scale_gaussian / log_scale_laplace), if it has one.
  std::optional<nn::HeadKind> spread() const;
  // From now on predict() draws intensity from the spread head's distribution around the mean
  // (infer/intensity_sampling.h) instead of the mean, its scale times the checkpoint's calibration
  // factor (nn::UNetConfig::spread_scale), or `scale_factor` in its place when given (1: the
  // uncalibrated model, for comparisons). Throws naming the checkpoint when it has no spread head.
  // `where` names the option in that error.
  void sample_from_spread(const IntensitySampling& sampling, const std::string& where,
                          std::optional<float> scale_factor = std::nullopt);
  bool sampling() const { return sampling_.has_value(); }
  // From now on the spread head's scale is multiplied by these terms' factors at each cell
  // (infer/intensity_spread_terms.h), in predict()'s draws and in predict_distribution().
  void set_spread_terms(std::vector<sensor::RangeNoiseTerm> terms) { spread_terms_ = std::move(terms); }
  // How the UNet's 3x3 kernels are chosen (nn/kernel_plan.h; rule until set), and what it chose.
  void set_kernel_mode(nn::PlanMode mode) { model_.set_kernel_plan(nn::KernelPlan(mode)); }
  const nn::KernelPlan& kernel_plan() const { return model_.kernel_plan(); }

  // Predicted target (intensity) per cell, [rows * cols]; cells without a return get 0. By
  // default the mean (channel 0); with sample_from_spread, a draw per cell depending only on
  // (seed, frame, cell): with a zero head (nn/heads.h zero_logit) the range's minimum with the
  // head's probability, otherwise from the spread around nn::nonzero_center.
  void predict(const pgm::PolarGridMap& pgm, std::vector<float>& out, std::uint64_t frame = 0);
  // The predicted distribution per cell, [rows * cols]: the mean (channel 0) and the spread head's
  // scale (clamped as in training, times the calibration factor in use). Cells without a return get
  // 0 in both. Throws naming the checkpoint when it has no spread head.
  void predict_distribution(const pgm::PolarGridMap& pgm, std::vector<float>& mean, std::vector<float>& scale);

 private:
  struct Setup {
    pgm::EncoderConfig encoder;
    pgm::BeamLayout layout;
  };
  // The encoder and beam layout that travel in the checkpoint's attributes; errors name the file
  // and the field as that file format places it (`attributes` + name, `in_channels`).
  static Setup setup_of(const nn::Checkpoint& meta, const std::filesystem::path& path, const std::string& attributes,
                        const std::string& in_channels);
  IntensityModel(nn::UNet model, pgm::EncoderConfig encoder, pgm::BeamLayout layout, std::filesystem::path path);
  void run(const pgm::PolarGridMap& pgm);  // encode and forward into output_
  const float* log_scale_channel(std::size_t cells) const;  // the spread head's channel in output_
  float scale_of(float log_scale) const;                    // clamped, times spread_scale_
  nn::UNet model_;
  pgm::EncoderConfig encoder_;
  pgm::BeamLayout layout_;
  std::filesystem::path path_;
  nn::Tensor input_, output_;
  std::optional<IntensitySampling> sampling_;
  float spread_scale_ = 1.f;  // applied to the spread head's scale: the checkpoint's, or sample_from_spread's
  std::vector<sensor::RangeNoiseTerm> spread_terms_;
};

}  // namespace lidarsim::infer
