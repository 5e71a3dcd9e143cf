#pragma once
// A model's weights in a plain binary file that needs no HDF5 to read: what the OSMP FMU ships
// (infer/fmu), so it carries no HDF5 runtime. Inference only: no optimizer, no training state.
// The training checkpoint (nn/checkpoint.h, HDF5) stays the source; `lidarsim_fmu_weights`
// (infer/fmu) converts one into the other, value for value.
//
// Layout ("lidarsim-weights 1"), every number little-endian:
//   bytes 0..18   the magic line "lidarsim-weights 1\n" (the digit is the format number: 2 when
//                 header.unet has "spread_scale", the spread head's calibration factor; 3 when it
//                 also has "spread_residual"; a model without either is written as 1, which
//                 older builds read)
//   8 bytes       H, the header's length in bytes (uint64)
//   H bytes       the header, a UTF-8 JSON object:
//                   "unet": {"in_channels", "outputs", "base", "depth", "row_affine_rows" (0: no
//                            per-row affine layer), "heads" (nn/heads.h text, "" = none),
//                            "lookup": {"classes" (0: no lookup base), "class_channel",
//                            "range_channel", "range_bins", "rows", "bin_width"},
//                            "spread_scale" (formats 2-3), "spread_residual" (format 3 only:
//                            {"levels", "mean_edges", "z", "target_step"}, nn/heads.h)}
//                   "attributes": {name: string}  (the checkpoint's free-form /config entries:
//                                                  input encoder, beam layout, ...)
//                   "params": [{"name": "<layer>/<field>", "shape": [n, c, h, w]}, ...]
//                            every parameter of the model, in the model's order
//                   "values": the number of floats that follow (the shapes' sum)
//                   "fnv1a64": 16 hex digits, FNV-1a 64 of the value bytes
//   values x 4    float32 parameter values, parameter after parameter (row-major, the layouts
//                 of nn/params.h), and nothing after them.
// Reading validates all of it before building anything; each problem is one lidarsim::Error
// "<file>: <field>: <what>".
#include <filesystem>
#include <map>
#include <string>

#include "nn/checkpoint.h"
#include "nn/unet.h"

namespace lidarsim::nn {

inline constexpr const char* kWeightsMagic = "lidarsim-weights ";

// Writes model's config and values with `attributes` (written atomically: temp file + rename).
void save_weights(const std::filesystem::path& path, const UNet& model,
                  const std::map<std::string, std::string>& attributes);

struct Weights {
  Checkpoint meta;  // unet and attributes filled; no optimizer, state zero
  UNet model;
};

// Reads and validates the whole file and returns the model with its values loaded.
Weights read_weights(const std::filesystem::path& path);

// True when the file begins with kWeightsMagic (false for a file that does not open).
bool is_weights_file(const std::filesystem::path& path);

}  // namespace lidarsim::nn
