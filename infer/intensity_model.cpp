#include "infer/intensity_model.h"

#include <algorithm>

#include "common/error.h"
#include "nn/checkpoint.h"
#include "pgm/projection.h"

namespace lidarsim::infer {

IntensityModel::IntensityModel(nn::UNet model, pgm::EncoderConfig encoder, pgm::BeamLayout layout,
                               std::filesystem::path path)
    : model_(std::move(model)), encoder_(std::move(encoder)), layout_(std::move(layout)), path_(std::move(path)) {}

IntensityModel IntensityModel::load(const std::filesystem::path& checkpoint) {
  if (!std::filesystem::exists(checkpoint)) throw input_error(checkpoint.string(), "file", "does not exist");
  const nn::Checkpoint meta = nn::read_checkpoint_meta(checkpoint);
  const auto enc = meta.attributes.find("encoder");
  if (enc == meta.attributes.end())
    throw input_error(checkpoint.string(), "/config/encoder", "missing: not a lidar-train checkpoint");
  pgm::EncoderConfig encoder = pgm::EncoderConfig::from_json(enc->second, checkpoint.string() + ": /config/encoder");
  if (encoder.input_channels() != meta.unet.in_channels)
    throw input_error(checkpoint.string(), "/config/unet.in_channels",
                      std::to_string(meta.unet.in_channels) + " but the encoder makes " +
                          std::to_string(encoder.input_channels()));
  const auto layout_text = meta.attributes.find("beam_layout");
  pgm::BeamLayout layout = layout_text != meta.attributes.end()
                               ? pgm::BeamLayout::from_json(layout_text->second, checkpoint.string() + ": /config/beam_layout")
                               : pgm::BeamLayout::hdl64e();
  nn::UNet model(meta.unet);
  nn::load_checkpoint(checkpoint, model, nullptr);
  return IntensityModel(std::move(model), std::move(encoder), std::move(layout), checkpoint);
}

std::vector<std::string> IntensityModel::extra_channels() const {
  std::vector<std::string> extra;
  for (const auto& c : encoder_.channels)
    if (std::find(pgm::kBaseChannels.begin(), pgm::kBaseChannels.end(), c) == pgm::kBaseChannels.end())
      extra.push_back(c);
  return extra;
}

void IntensityModel::predict(const pgm::PolarGridMap& pgm, std::vector<float>& out) {
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
  const float* mask = pgm.channel("mask");
  out.assign(pgm.cells(), 0.f);
  for (std::size_t i = 0; i < pgm.cells(); ++i) out[i] = mask[i] > 0 ? output_.data()[i] : 0.f;
}

}  // namespace lidarsim::infer
