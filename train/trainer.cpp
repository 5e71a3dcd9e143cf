#include "train/trainer.h"

#include <algorithm>
#include <memory>

#include "common/error.h"
#include "nn/checkpoint.h"
#include "train/data_parallel.h"
#include "train/distributed.h"
#include "train/lookup_fit.h"
#include "train/run_settings.h"
#include "train/training_run.h"

namespace lidarsim::train {
namespace {

std::vector<std::string> required_channels(const pgm::EncoderConfig& encoder) {
  std::vector<std::string> names;
  for (const auto& c : encoder.channels)
    if (c != "mask") names.push_back(c);
  return names;
}

}  // namespace

std::atomic<bool>& stop_requested() {
  static std::atomic<bool> flag{false};
  return flag;
}

nn::Tensor predict_dataset(nn::UNet& model, const pgm::EncoderConfig& encoder, const data::Dataset& dataset) {
  const int rows = dataset.rows(), cols = dataset.cols();
  nn::Tensor out(dataset.size(), 1, rows, cols);
  nn::Tensor input(1, encoder.input_channels(), rows, cols), pred;
  for (int n = 0; n < dataset.size(); ++n) {
    pgm::encode_input(dataset.view(n), encoder, input, 0);
    model.predict(input, pred);
    // Channel 0 is the mean intensity whatever heads follow it (nn/heads.h).
    std::copy_n(pred.begin(), static_cast<std::ptrdiff_t>(rows) * cols, out.image(n));
  }
  return out;
}

pgm::EncoderConfig encoder_from_checkpoint(const std::filesystem::path& checkpoint) {
  const nn::Checkpoint meta = nn::read_checkpoint_meta(checkpoint);
  const auto it = meta.attributes.find("encoder");
  if (it == meta.attributes.end())
    throw input_error(checkpoint.string(), "/config/encoder", "missing: not a lidar-train checkpoint");
  return pgm::EncoderConfig::from_json(it->second, checkpoint.string() + ": /config/encoder");
}

TrainResult train(const TrainConfig& config, const std::function<void(const EpochReport&)>& on_epoch) {
  std::vector<std::unique_ptr<data::FrameSource>> sets;
  std::unique_ptr<data::FrameSource> val_set;
  // Headers only: frames are read when a step or the validation needs them. A rank that cannot
  // open a file is reported by rank 0 (distributed.h).
  agreed([&] {
    if (config.data.empty()) throw Error("lidar-train: no training data given");
    validate_settings(config);  // before reading gigabytes of data
    const auto channels = required_channels(config.encoder);
    const std::size_t cache = static_cast<std::size_t>(config.cache_mb) << 20;
    for (const auto& path : config.data) sets.push_back(data::open_frame_source(path, channels, cache));
    for (const auto& path : config.train_also) sets.push_back(data::open_frame_source(path, channels, cache));
    if (config.validation) val_set = data::open_frame_source(*config.validation, channels, cache);
  });
  std::vector<const data::FrameSource*> views;
  for (const auto& set : sets) views.push_back(set.get());
  return train_frames(config, views, val_set.get(), on_epoch);
}

TrainResult train_on(const TrainConfig& config, const std::vector<const data::Dataset*>& sets,
                     const std::vector<std::string>& names, const data::Dataset* validation,
                     const std::function<void(const EpochReport&)>& on_epoch) {
  std::vector<std::unique_ptr<data::FrameSource>> sources;
  std::vector<const data::FrameSource*> views;
  for (std::size_t i = 0; i < sets.size(); ++i) {
    sources.push_back(data::memory_frame_source(*sets[i], names.at(i)));
    views.push_back(sources.back().get());
  }
  std::unique_ptr<data::FrameSource> val_set;
  if (validation) val_set = data::memory_frame_source(*validation, "validation dataset");
  return train_frames(config, views, val_set.get(), on_epoch);
}

TrainResult train_frames(const TrainConfig& requested, const std::vector<const data::FrameSource*>& train_sets,
                         const data::FrameSource* val_set, const std::function<void(const EpochReport&)>& on_epoch) {
  Distributed& dist = Distributed::world();
  TrainConfig config = requested;
  const LookupForm lookup_form = parse_lookup_form(config.lookup_form);
  if (config.lookup_base && lookup_form == LookupForm::classes) config.encoder.class_groups = one_group_per_class();
  bool set_up = false;
  if (!dist.active()) return train_on_ranks(config, lookup_form, train_sets, val_set, on_epoch, set_up);
  try {
    return train_on_ranks(config, lookup_form, train_sets, val_set, on_epoch, set_up);
  } catch (const AgreedError&) {
    throw;
  } catch (const std::exception& e) {
    // Set-up makes no collective call before its end, where every rank agrees: a failing rank
    // joins that agreement here. Later, the other ranks may be waiting in another collective.
    if (!set_up) dist.agree(e.what());
    dist.abort(e.what());
  }
}

}  // namespace lidarsim::train
