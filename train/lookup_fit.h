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

// One class group per class id (pgm/materials.h), named after the class: with these as the
// encoder's class_groups the table is keyed by every class, as the intensity loop's lookup is
// (`lidar-train --lookup-base=classes`); the default groups merge 23 ids into 14.
std::vector<pgm::ClassGroup> one_group_per_class();

// How the per-beam offsets are fitted on the training residuals over the table:
//   mean  the plain mean per row
//   loop  as the intensity loop fits its per-beam table (qualify/intensity/intensity.h, --base lookup):
//         residuals winsorised at the 1st and 99th percentile of all training residuals, then
//         sum / (n + 5) per row. With one_group_per_class() the untrained model then equals the
//         loop's "class x range + per-beam table", the best lookup on the guarded split.
enum class BeamFit { mean, loop };

struct LookupFit {
  std::vector<float> table;  // [(classes + 1) * range_bins]: mean target per (group, range bin)
  std::vector<float> beam;   // [rows]: mean residual over the table per row
  long cells = 0;            // training cells fitted on
};

// Fits on every training cell of `frames` (validation and guard columns excluded by the split
// the frames carry): the mean target per (group, bin), falling back to the group's mean, then
// the global mean, where a key has no cell; then the mean of (target - table) per row.
LookupFit fit_lookup_base(const nn::LookupBaseConfig& config, const TrainingFrames& frames, int cols,
                          BeamFit beam_fit = BeamFit::mean);

// Writes a fit into the model's "lookup/table" and "lookup/beam".
void set_lookup_base(nn::UNet& model, const LookupFit& fit);

}  // namespace lidarsim::train
