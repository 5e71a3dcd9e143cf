#pragma once
// The settings of a training run (train/trainer.h TrainConfig): which combinations can work,
// what a checkpoint records of them and which differences a resume accepts. Internal to train/.
#include <string>

#include <nlohmann/json.hpp>

#include "nn/checkpoint.h"
#include "train/trainer.h"

namespace lidarsim::train {

// Settings that cannot work, refused before anything is read or allocated.
void validate_settings(const TrainConfig& c);

// Every setting that changes the run's result (the checkpoint stores it as train_config and a
// resume compares it key by key, so a setting added here is checked on resume too).
nlohmann::json run_settings(const TrainConfig& c);
std::string describe_config(const TrainConfig& c);

// Refuses a resume whose settings differ from the checkpoint's, except those the user named.
void check_resume_settings(const TrainConfig& c, const nn::Checkpoint& meta);

}  // namespace lidarsim::train
