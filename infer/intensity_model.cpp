#include "infer/intensity_model.h"

#include <algorithm>
#include <cmath>

#include "common/error.h"
#include "infer/intensity_spread_terms.h"
#include "nn/checkpoint_weights.h"
#include "pgm/projection.h"

namespace lidarsim::infer {

IntensityModel::IntensityModel(nn::UNet model, pgm::EncoderConfig encoder, pgm::BeamLayout layout,
                               std::filesystem::path path)
    : model_(std::move(model)),
      encoder_(std::move(encoder)),
      layout_(std::move(layout)),
      path_(std::move(path)),
      spread_scale_(model_.config().spread_scale) {}

IntensityModel::Setup IntensityModel::setup_of(const nn::Checkpoint& meta, const std::filesystem::path& path,
                                               const std::string& attributes, const std::string& in_channels) {
  const auto enc = meta.attributes.find("encoder");
  if (enc == meta.attributes.end())
    throw input_error(path.string(), attributes + "encoder", "missing: not a lidar-train checkpoint");
  pgm::EncoderConfig encoder = pgm::EncoderConfig::from_json(enc->second, path.string() + ": " + attributes + "encoder");
  if (encoder.input_channels() != meta.unet.in_channels)
    throw input_error(path.string(), in_channels,
                      std::to_string(meta.unet.in_channels) + " but the encoder makes " +
                          std::to_string(encoder.input_channels()));
  const auto layout_text = meta.attributes.find("beam_layout");
  pgm::BeamLayout layout = layout_text != meta.attributes.end()
                               ? pgm::BeamLayout::from_json(layout_text->second, path.string() + ": " + attributes + "beam_layout")
                               : pgm::BeamLayout::hdl64e();
  return {std::move(encoder), std::move(layout)};
}

IntensityModel IntensityModel::load_weights(const std::filesystem::path& weights) {
  if (!std::filesystem::exists(weights)) throw input_error(weights.string(), "file", "does not exist");
  nn::Weights w = nn::read_weights(weights);
  Setup setup = setup_of(w.meta, weights, "header.attributes.", "header.unet.in_channels");
  return IntensityModel(std::move(w.model), std::move(setup.encoder), std::move(setup.layout), weights);
}

std::vector<std::string> IntensityModel::extra_channels() const {
  std::vector<std::string> extra;
  for (const auto& c : encoder_.channels)
    if (std::find(pgm::kBaseChannels.begin(), pgm::kBaseChannels.end(), c) == pgm::kBaseChannels.end())
      extra.push_back(c);
  return extra;
}

std::optional<nn::HeadKind> IntensityModel::spread() const {
  for (nn::HeadKind h : model_.config().heads)
    if (h == nn::HeadKind::log_scale_gaussian || h == nn::HeadKind::log_scale_laplace) return h;
  return std::nullopt;
}

void IntensityModel::sample_from_spread(const IntensitySampling& sampling, const std::string& where,
                                        std::optional<float> scale_factor) {
  if (!spread())
    throw input_error(path_.string(), "/config/unet.heads",
                      where + " needs a spread head (heads: " +
                          (model_.config().heads.empty() ? std::string("mean") : nn::heads_text(model_.config().heads)) +
                          "); train with lidar-train --heads mean,log_scale_laplace");
  if (scale_factor && !(*scale_factor > 0 && std::isfinite(*scale_factor)))
    throw Error(where + ": the scale factor must be a finite number > 0, got " + std::to_string(*scale_factor));
  if (!(sampling.min < sampling.max))
    throw Error(where + ": the intensity range must have min < max, got [" + std::to_string(sampling.min) + ", " +
                std::to_string(sampling.max) + "]");
  sampling_ = sampling;
  spread_scale_ = scale_factor.value_or(model_.config().spread_scale);
}

void IntensityModel::run(const pgm::PolarGridMap& pgm) {
  const int rows = pgm.rows(), cols = pgm.cols();
  const int model_rows = model_.config().row_affine_rows;
  if (model_rows > 0 && rows != model_rows)
    throw input_error(path_.string(), "/config/unet.row_affine_rows",
                      "the model has a gain per laser for " + std::to_string(model_rows) + " rows, the grid has " +
                          std::to_string(rows));
  if (input_.shape() != nn::Shape{1, encoder_.input_channels(), rows, cols})
    input_.resize({1, encoder_.input_channels(), rows, cols});
  pgm::encode_input(pgm::view_of(pgm), encoder_, input_, 0);
  model_.predict(input_, output_);
}

const float* IntensityModel::log_scale_channel(std::size_t cells) const {
  const auto heads = model_.config().heads;
  const auto at = std::find(heads.begin(), heads.end(), *spread()) - heads.begin();
  return output_.data() + static_cast<std::size_t>(at) * cells;
}

float IntensityModel::scale_of(float log_scale) const {
  const nn::LogScaleClamp clamp{};  // as in training (nn/loss.h)
  // The calibration factor fitted after training (1 for checkpoints without one, formats 1-2).
  return spread_scale_ * std::exp(std::clamp(log_scale, clamp.min, clamp.max));
}

void IntensityModel::predict(const pgm::PolarGridMap& pgm, std::vector<float>& out, std::uint64_t frame) {
  run(pgm);
  const float* mask = pgm.channel("mask");
  out.assign(pgm.cells(), 0.f);
  const float* mean = output_.data();  // channel 0 whatever heads follow (nn/heads.h)
  if (!sampling_) {
    for (std::size_t i = 0; i < pgm.cells(); ++i) out[i] = mask[i] > 0 ? mean[i] : 0.f;
    return;
  }
  const float* log_scale = log_scale_channel(pgm.cells());
  // The empirical residual fitted with the scale when the checkpoint has one (format 4).
  const nn::SpreadResidual& residual = model_.config().spread_residual;
  const bool empirical = !residual.empty() && !sampling_->parametric;
  // With a zero head: 0 with its probability, otherwise a draw around the centre of the values
  // that are not 0 (the residual table was fitted around the same centre).
  const int zc = nn::head_channel(model_.config().heads, nn::HeadKind::zero_logit);
  const float* zero_logit = zc >= 0 ? output_.data() + static_cast<std::size_t>(zc) * pgm.cells() : nullptr;
  const SpreadTermFactor terms(spread_terms_, pgm);
  for (std::size_t i = 0; i < pgm.cells(); ++i) {
    if (mask[i] <= 0) continue;
    float centre = mean[i];
    if (zero_logit) {
      const double p_zero = nn::logit_probability(zero_logit[i]);
      if (draws_zero(p_zero, *sampling_, frame, i)) {
        out[i] = sampling_->min;
        continue;
      }
      centre = static_cast<float>(nn::nonzero_center(mean[i], p_zero));
    }
    const float scale = scale_of(log_scale[i]) * static_cast<float>(terms.at(i, mean[i]));
    out[i] = empirical ? sample_intensity_empirical(residual, centre, scale, *sampling_, frame, i)
                       : sample_intensity(*spread(), centre, scale, *sampling_, frame, i);
  }
}

void IntensityModel::predict_distribution(const pgm::PolarGridMap& pgm, std::vector<float>& mean,
                                          std::vector<float>& scale) {
  if (!spread())
    throw input_error(path_.string(), "/config/unet.heads", "predict_distribution needs a spread head");
  run(pgm);
  const float* mask = pgm.channel("mask");
  const float* log_scale = log_scale_channel(pgm.cells());
  mean.assign(pgm.cells(), 0.f);
  scale.assign(pgm.cells(), 0.f);
  const SpreadTermFactor terms(spread_terms_, pgm);
  for (std::size_t i = 0; i < pgm.cells(); ++i)
    if (mask[i] > 0) mean[i] = output_.data()[i], scale[i] = scale_of(log_scale[i]) * static_cast<float>(terms.at(i, mean[i]));
}

}  // namespace lidarsim::infer
