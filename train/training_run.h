#pragma once
// One training run on this rank (train/trainer.h train_frames comes here): data and split, the
// early-stopping hold-out, model and optimizer (resumed from a checkpoint when asked), the lookup
// base, the loop of steps and epochs, and the choice of the epoch kept. Internal to train/.
#include <functional>
#include <vector>

#include "data/frame_source.h"
#include "train/trainer.h"

namespace lidarsim::train {

// `lookup_form` is config.lookup_form parsed. `set_up` turns true once every rank has read its
// data, built its model and agreed to start: before that a failing rank has made no collective
// call, after it the others may be waiting in one.
TrainResult train_on_ranks(const TrainConfig& config, LookupForm lookup_form,
                           const std::vector<const data::FrameSource*>& train_sets, const data::FrameSource* val_set,
                           const std::function<void(const EpochReport&)>& on_epoch, bool& set_up);

}  // namespace lidarsim::train
