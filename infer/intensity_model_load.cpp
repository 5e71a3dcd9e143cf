// IntensityModel::load, the one reader of HDF5 checkpoints in infer/: a translation unit of its
// own, so code that loads only weights files (the OSMP FMU) links no HDF5.
#include "common/error.h"
#include "infer/intensity_model.h"
#include "nn/checkpoint.h"
#include "nn/checkpoint_weights.h"

namespace lidarsim::infer {

IntensityModel IntensityModel::load(const std::filesystem::path& checkpoint) {
  if (!std::filesystem::exists(checkpoint)) throw input_error(checkpoint.string(), "file", "does not exist");
  if (nn::is_weights_file(checkpoint)) return load_weights(checkpoint);
  const nn::Checkpoint meta = nn::read_checkpoint_meta(checkpoint);
  Setup setup = setup_of(meta, checkpoint, "/config/", "/config/unet.in_channels");
  nn::UNet model(meta.unet);
  nn::load_checkpoint(checkpoint, model, nullptr);
  return IntensityModel(std::move(model), std::move(setup.encoder), std::move(setup.layout), checkpoint);
}

}  // namespace lidarsim::infer
