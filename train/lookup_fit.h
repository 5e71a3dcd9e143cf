#pragma once
// The lookup base of a UNet (nn/unet.h, lookup): a class x range table plus one offset per beam
// row, fitted on the training cells only, so the network learns the residual over the best
// lookup baseline and starts out predicting exactly that lookup.
#include <vector>

#include "nn/unet.h"
#include "pgm/encoder.h"
#include "train/frame_batches.h"

namespace lidarsim::train {

// Where the table finds its keys in this encoder's input: the "range" channel and the one-hot
// class groups (5 m bins up to 80 m, then one bin beyond, as data/baselines.h); `rows` beam rows.
// Throws naming what is missing (the encoder must have range and one-hot class channels).
nn::LookupBaseConfig lookup_base_config(const pgm::EncoderConfig& encoder, int rows);

struct LookupFit {
  std::vector<float> table;  // [(classes + 1) * range_bins]: mean target per (group, range bin)
  std::vector<float> beam;   // [rows]: mean residual over the table per row
  long cells = 0;            // training cells fitted on
};

// Fits on every training cell of `frames` (validation and guard columns excluded by the split
// the frames carry): the mean target per (group, bin), falling back to the group's mean, then
// the global mean, where a key has no cell; then the mean of (target - table) per row.
LookupFit fit_lookup_base(const nn::LookupBaseConfig& config, const TrainingFrames& frames, int cols);

// Writes a fit into the model's "lookup/table" and "lookup/beam".
void set_lookup_base(nn::UNet& model, const LookupFit& fit);

}  // namespace lidarsim::train
