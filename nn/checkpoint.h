#pragma once
// HDF5 checkpoints, readable with h5py:
//   /config          attributes: format ("lidarsim-checkpoint 1" to "... 4"; absent = 1;
//                    a number above 4 is refused by name), unet.in_channels, unet.out_channels (format 1:
//                    one output, no heads) or unet.outputs and unet.heads (format 2: several
//                    outputs or named heads, nn/heads.h; builds before format 2 refuse these
//                    files as missing unet.out_channels), unet.spread_scale (formats 3-4: the
//                    spread head's calibration factor; builds that read 1-2 refuse the format),
//                    unet.spread_residual (format 4 only: JSON, nn/heads.h SpreadResidual, the
//                    residual's quantiles and the targets' grid; builds that read 1-3 refuse it),
//                    unet.base, unet.depth,
//                    unet.row_affine_rows (only when the model has the per-row affine layer;
//                    absent = no layer, so files without it load),
//                    unet.lookup.{classes, class_channel, range_channel, range_bins, rows,
//                    bin_width} (only with a lookup base; its table is under /params/lookup),
//                    optimizer.* and every entry of Checkpoint::attributes (string values;
//                    the input encoder, beam layout, lambda, seed travel here as text/JSON)
//   /params/<layer>/<field>       float32 datasets with the parameter's shape (PyTorch layouts:
//                                 conv [out, in, k, k], transposed conv [in, out, 2, 2], bias [out])
//   /optimizer/m/<layer>/<field>, /optimizer/v/<layer>/<field>, attribute steps
//   /state           attributes epoch, step; dataset rng (the training RNG state as text)
// Written to a temporary file and renamed; loading validates every shape and names the first
// mismatch in a lidarsim::Error that names the file.
#include <cstdint>
#include <filesystem>
#include <map>
#include <optional>
#include <string>

#include "nn/optim.h"
#include "nn/unet.h"

namespace lidarsim::nn {

struct TrainState {
  std::int64_t epoch = 0;
  std::int64_t step = 0;
  std::string rng;  // serialised RNG state (std::mt19937_64 << stream)
};

struct Checkpoint {
  UNetConfig unet;
  std::map<std::string, std::string> attributes;  // free-form config from the layers above
  TrainState state;
  // Filled by read_checkpoint_meta() when the file holds an optimizer (save takes it from the
  // Optimizer itself and ignores this field), so training can resume with the same settings.
  std::optional<OptimizerConfig> optimizer;
};

// Writes the model's own config (meta.unet is not consulted), meta.attributes (names starting
// with "unet." or "optimizer." and "format" are reserved) and meta.state; optimizer may be null.
void save_checkpoint(const std::filesystem::path& path, const UNet& model, const Optimizer* optimizer,
                     const Checkpoint& meta);

// Reads only /config and /state (to build the model before loading its weights).
Checkpoint read_checkpoint_meta(const std::filesystem::path& path);

// Loads parameters into `model` (whose config must match) and, when given, the optimizer state.
// Everything is validated before anything is copied: on an Error the model is unchanged.
void load_checkpoint(const std::filesystem::path& path, UNet& model, Optimizer* optimizer);

}  // namespace lidarsim::nn
