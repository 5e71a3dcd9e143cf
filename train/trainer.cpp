#include "train/trainer.h"

#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <numeric>
#include <random>

#include <nlohmann/json.hpp>

#include "common/error.h"
#include "common/progress.h"
#include "nn/checkpoint.h"
#include "nn/loss.h"
#include "nn/optim.h"
#include "nn/receptive_field.h"
#include "train/distributed.h"
#include "train/early_stop.h"
#include "train/frame_batches.h"
#include "train/lookup_fit.h"
#include "train/residual_shrink.h"
#include "train/prefetcher.h"

namespace lidarsim::train {
namespace {

float learning_rate(const TrainConfig& c, std::int64_t step, std::int64_t total_steps) {
  const double progress = total_steps > 1 ? static_cast<double>(step) / (total_steps - 1) : 0.0;
  const double floor = c.final_lr_fraction;
  return static_cast<float>(c.lr * (floor + (1 - floor) * 0.5 * (1 + std::cos(M_PI * progress))));
}

data::SectorSplit all_validation() {
  data::SectorSplit split;
  split.validation.resize(static_cast<std::size_t>(split.sectors));
  std::iota(split.validation.begin(), split.validation.end(), 0);
  return split;
}

// Cell-weighted merge of metrics from several datasets.
data::Metrics merge(const std::vector<data::Metrics>& parts) {
  data::Metrics m;
  double abs_sum = 0, sq_sum = 0;
  for (const auto& p : parts) {
    abs_sum += p.mae * p.cells;
    sq_sum += p.rmse * p.rmse * p.cells;
    m.cells += p.cells;
  }
  if (m.cells > 0) {
    m.mae = abs_sum / m.cells;
    m.rmse = std::sqrt(sq_sum / m.cells);
  }
  return m;
}

std::vector<std::string> required_channels(const pgm::EncoderConfig& encoder) {
  std::vector<std::string> names;
  for (const auto& c : encoder.channels)
    if (c != "mask") names.push_back(c);
  return names;
}

// Every setting that changes the run's result (the checkpoint stores it as train_config and a
// resume compares it key by key, so a setting added here is checked on resume too).
nlohmann::json run_settings(const TrainConfig& c) {
  nlohmann::json j;
  std::vector<std::string> data;
  for (const auto& p : c.data) data.push_back(p.string());
  j["data"] = data;
  j["validation"] = c.validation ? c.validation->string() : "split " + c.split + " of --data";
  if (!c.train_also.empty()) {  // absent when none: older checkpoints compare equal
    std::vector<std::string> also;
    for (const auto& p : c.train_also) also.push_back(p.string());
    j["train_also"] = also;
  }
  j["channels"] = c.encoder.channels;
  j["base"] = c.base;
  j["depth"] = c.depth;
  if (c.row_affine) j["row_affine"] = true;  // absent when off: older checkpoints compare equal
  if (c.lookup_base) j["lookup_base"] = true;
  if (c.lookup_base && c.lookup_form != "groups") j["lookup_form"] = c.lookup_form;
  if (c.early_stop) j["early_stop"] = {{"inner_columns", c.inner_columns}, {"patience", c.patience}};
  if (c.early_stop && !c.inner_frames.empty()) j["early_stop"]["inner_frames"] = c.inner_frames;
  if (c.shrink_residual) j["shrink_residual"] = true;
  j["epochs"] = c.epochs;
  j["steps_per_epoch"] = c.steps_per_epoch;
  j["batch"] = c.batch;
  j["crop_columns"] = c.crop_columns;
  j["lr"] = c.lr;
  j["final_lr_fraction"] = c.final_lr_fraction;
  j["lambda"] = c.lambda;
  j["seed"] = c.seed;
  j["augment_roll"] = c.augment_roll;
  j["augment_mirror"] = c.augment_mirror;
  j["threads"] = c.threads;  // results are bit-identical only with the same thread count
  j["ranks"] = Distributed::world().size();  // ... and the same number of MPI ranks
  return j;
}

std::string describe_config(const TrainConfig& c) { return run_settings(c).dump(); }

// Refuses a resume whose settings differ from the checkpoint's, except those the user named.
void check_resume_settings(const TrainConfig& c, const nn::Checkpoint& meta) {
  const auto stored_text = meta.attributes.find("train_config");
  if (stored_text == meta.attributes.end()) return;  // checkpoints from before train_config
  nlohmann::json stored;
  try {
    stored = nlohmann::json::parse(stored_text->second);
  } catch (const nlohmann::json::exception&) {
    throw input_error(c.out.string(), "/config/train_config", "not valid JSON");
  }
  if (!stored.is_object()) throw input_error(c.out.string(), "/config/train_config", "expected a JSON object");
  const nlohmann::json now = run_settings(c);
  std::string differences, names;
  for (const auto& [key, value] : now.items()) {
    if (!stored.contains(key) || stored[key] == value) continue;
    const bool overridden = std::find(c.resume_overrides.begin(), c.resume_overrides.end(), key) != c.resume_overrides.end();
    if (overridden) {
      if (Distributed::world().root())
        std::fprintf(stderr, "lidar-train: resuming with %s %s (the checkpoint has %s), as overridden\n", key.c_str(),
                   value.dump().c_str(), stored[key].dump().c_str());
      continue;
    }
    differences += (differences.empty() ? "" : ", ") + key + " " + stored[key].dump() + " -> " + value.dump();
    names += (names.empty() ? "" : ",") + key;
  }
  if (!differences.empty())
    throw input_error(c.out.string(), "/config/train_config",
                      "resume with other settings than the checkpoint's (" + differences +
                          "); the run would not continue the same training. Pass --override " + names +
                          " to resume anyway");
}

// Settings that cannot work, refused before anything is read or allocated.
void validate_settings(const TrainConfig& c) {
  auto refuse = [](const std::string& option, const std::string& rule, const std::string& got) {
    throw Error("lidar-train: --" + option + ": " + rule + ", got " + got);
  };
  if (c.epochs < 1 || c.epochs > 1000000) refuse("epochs", "must be in [1, 1000000]", std::to_string(c.epochs));
  if (c.steps_per_epoch < 0 || c.steps_per_epoch > 100000000)
    refuse("steps-per-epoch", "must be in [0, 100000000] (0: one pass over the frames)", std::to_string(c.steps_per_epoch));
  if (c.batch < 1 || c.batch > 256) refuse("batch", "must be in [1, 256]", std::to_string(c.batch));
  const int ranks = Distributed::world().size();
  if (c.batch % ranks != 0)
    refuse("batch", "the global batch must be a multiple of the " + std::to_string(ranks) + " MPI ranks", std::to_string(c.batch));
  if (c.threads < 1 || c.threads > 1024) refuse("threads", "must be in [1, 1024]", std::to_string(c.threads));
  if (c.cache_mb < 0 || c.cache_mb > 1048576) refuse("cache-mb", "must be in [0, 1048576]", std::to_string(c.cache_mb));
  if (c.base < 1 || c.base > 1024) refuse("base", "must be in [1, 1024]", std::to_string(c.base));
  if (c.depth < 1 || c.depth > 10) refuse("depth", "must be in [1, 10]", std::to_string(c.depth));
  const int multiple = 1 << c.depth;
  if (c.crop_columns < 0 || c.crop_columns % multiple != 0)
    refuse("crop", "must be 0 (whole scans) or a positive multiple of 2^depth = " + std::to_string(multiple),
           std::to_string(c.crop_columns));
  if (!(c.lr > 0) || !std::isfinite(c.lr)) refuse("lr", "must be a finite number > 0", std::to_string(c.lr));
  if (!(c.lambda >= 0) || !std::isfinite(c.lambda)) refuse("lambda", "must be a finite number >= 0", std::to_string(c.lambda));
  if (!(c.final_lr_fraction >= 0 && c.final_lr_fraction <= 1))
    refuse("final-lr-fraction", "must be in [0, 1]", std::to_string(c.final_lr_fraction));
  if (c.lookup_form != "groups" && c.lookup_form != "classes")
    refuse("lookup-base", "must be groups or classes", "\"" + c.lookup_form + "\"");
  if (c.inner_columns < 1 || c.inner_columns > 100000)
    refuse("inner-columns", "must be in [1, 100000]", std::to_string(c.inner_columns));
  if (c.shrink_residual && !(c.lookup_base && c.early_stop))
    refuse("shrink-residual", "needs --lookup-base and --early-stop (the factor is chosen on the inner region)",
           c.lookup_base ? "no --early-stop" : "no --lookup-base");
  if (c.patience < 0 || c.patience > 1000000) refuse("patience", "must be in [0, 1000000] (0: every epoch)", std::to_string(c.patience));
}

// One step's gradients over every rank's part of the batch (x, y, m hold this rank's part):
// the loss is normalised by the cells of the whole global batch, the parameter gradients are
// summed in rank order, failures (a frame this rank could not read: `read_error`) and stop
// requests are agreed on before anything changes. Returns the data loss of the whole batch;
// `stop` is set when any rank was asked to stop.
double data_parallel_gradients(nn::UNet& model, const nn::Tensor& x, const nn::Tensor& y, const nn::Tensor& m,
                               const std::string& read_error, nn::Tensor& pred, nn::Tensor& d_pred, bool& stop) {
  Distributed& dist = Distributed::world();
  std::int64_t valid = 0;
  if (read_error.empty())
    for (const float v : m) valid += v != 0.f;
  dist.sum(&valid, 1);
  std::string error = read_error;
  double status[3] = {0, error.empty() ? 0.0 : 1.0, stop_requested().load() ? 1.0 : 0.0};  // loss, failed ranks, stops
  if (error.empty()) {
    try {
      model.forward(x, pred);
      status[0] = nn::masked_mse(pred, y, m, &d_pred, static_cast<long>(valid)).data;
      model.backward(d_pred);
    } catch (const std::exception& e) {
      error = *e.what() ? e.what() : "unknown error";
      status[1] = 1;
    }
  }
  dist.sum_in_rank_order(status, 3);
  if (status[1] > 0) dist.agree(error);  // throws on every rank
  dist.sum_in_rank_order(model.params().grads(), model.params().size());
  stop = status[2] > 0;
  return status[0];
}

}  // namespace

std::atomic<bool>& stop_requested() {
  static std::atomic<bool> flag{false};
  return flag;
}

namespace {

// Runs `f` (no collective calls inside) and agrees with the other ranks on whether it failed.
template <class F>
void agreed(F&& f) {
  Distributed& dist = Distributed::world();
  if (!dist.active()) return f();
  std::string error;
  try {
    f();
  } catch (const std::exception& e) {
    error = *e.what() ? e.what() : "unknown error";
  }
  dist.agree(error);
}

TrainResult train_on_ranks(const TrainConfig& config, const std::vector<const data::FrameSource*>& train_sets,
                           const data::FrameSource* val_set, const std::function<void(const EpochReport&)>& on_epoch,
                           bool& set_up);

}  // namespace

nn::Tensor predict_dataset(nn::UNet& model, const pgm::EncoderConfig& encoder, const data::Dataset& dataset) {
  const int rows = dataset.rows(), cols = dataset.cols();
  nn::Tensor out(dataset.size(), 1, rows, cols);
  nn::Tensor input(1, encoder.input_channels(), rows, cols), pred;
  for (int n = 0; n < dataset.size(); ++n) {
    pgm::encode_input(dataset.view(n), encoder, input, 0);
    model.predict(input, pred);
    std::copy(pred.begin(), pred.end(), out.image(n));
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
  if (config.lookup_base && config.lookup_form == "classes") config.encoder.class_groups = one_group_per_class();
  bool set_up = false;
  if (!dist.active()) return train_on_ranks(config, train_sets, val_set, on_epoch, set_up);
  try {
    return train_on_ranks(config, train_sets, val_set, on_epoch, set_up);
  } catch (const AgreedError&) {
    throw;
  } catch (const std::exception& e) {
    // Set-up makes no collective call before its end, where every rank agrees: a failing rank
    // joins that agreement here. Later, the other ranks may be waiting in another collective.
    if (!set_up) dist.agree(e.what());
    dist.abort(e.what());
  }
}

namespace {

int split_sets_of(const std::vector<const data::FrameSource*>& sets, const TrainConfig& c) {
  return static_cast<int>(sets.size() - std::min(sets.size(), c.train_also.size()));
}

TrainResult train_on_ranks(const TrainConfig& config, const std::vector<const data::FrameSource*>& train_sets,
                           const data::FrameSource* val_set, const std::function<void(const EpochReport&)>& on_epoch,
                           bool& set_up) {
  Distributed& dist = Distributed::world();
  if (train_sets.empty()) throw Error("lidar-train: no training data given");
  validate_settings(config);
  omp_set_num_threads(config.threads);
  // Reading on a background thread needs an HDF5 built thread-safe (checkpoints are written meanwhile).
  bool prefetch = config.prefetch;
  for (const data::FrameSource* set : train_sets) prefetch = prefetch && set->reads_overlap_other_hdf5();
  if (val_set) prefetch = prefetch && val_set->reads_overlap_other_hdf5();

  // --- data: headers now, frames when a step needs them ----------------------------------------
  const int rows = train_sets[0]->rows(), cols = train_sets[0]->cols();
  for (std::size_t i = 0; i < train_sets.size(); ++i)
    if (train_sets[i]->rows() != rows || train_sets[i]->cols() != cols)
      throw input_error(train_sets[i]->name(), "/pgm", "grid " + std::to_string(train_sets[i]->rows()) + " x " +
                                                  std::to_string(train_sets[i]->cols()) + " differs from " +
                                                  std::to_string(rows) + " x " + std::to_string(cols));
  const bool sector_split = val_set == nullptr;
  const int in_channels = config.encoder.input_channels();
  nn::UNetConfig arch{in_channels, 1, config.base, config.depth, config.row_affine ? rows : 0};
  if (config.lookup_base) arch.lookup = lookup_base_config(config.encoder, rows);
  const int half_width = nn::receptive_field_half_width(arch);
  const data::SectorSplit split = data::parse_split(config.split, half_width, cols);
  if (sector_split && split.validation_frames.empty() && !split.regions.empty() && split.guard_columns < 2 * half_width)
    throw Error("lidar-train: --split " + config.split + ": guard bands of " + std::to_string(split.guard_columns) +
                " columns are narrower than twice the model's receptive-field half-width (" +
                std::to_string(half_width) + " columns): validation would leak");
  if (sector_split && config.progress && dist.root())
    std::fprintf(stderr, "lidar-train: receptive field half-width %d columns; split: %s\n", half_width,
                 split.describe(cols).c_str());
  // Early stopping: the network trains outside the inner region and its guard band too.
  std::optional<data::SectorSplit> inner;
  data::SectorSplit train_split = split;
  std::string inner_text;
  if (config.early_stop) {
    if (!sector_split)
      throw Error("lidar-train: --early-stop: needs the split of --data (not --val): the inner region is carved out of its training columns");
    // Frames name places; a column split has no frame to hold out, so the option would be ignored.
    if (split.validation_frames.empty() && !config.inner_frames.empty())
      throw Error("lidar-train: --inner-frames: needs --split frames:...; with a column split the inner region is columns (--inner-columns)");
    if (!split.validation_frames.empty()) {
      if (config.inner_frames.empty())
        throw Error("lidar-train: --early-stop with --split frames:...: needs --inner-frames ID,... (training frames of other places)");
      inner = data::inner_frames_split(split, config.inner_frames);
      train_split = data::with_inner(split, *inner);
      long inner_n = 0, train_n = 0;
      for (int k = 0; k < split_sets_of(train_sets, config); ++k)
        for (const auto& id : train_sets[static_cast<std::size_t>(k)]->header().frames) {
          if (split.roles(1, id)[0] != data::kTrain) continue;
          (inner->roles(1, id)[0] == data::kValidation ? inner_n : train_n) += 1;
        }
      if (inner_n == 0 || train_n == 0)
        throw Error("lidar-train: --inner-frames: " + std::to_string(inner_n) + " inner and " + std::to_string(train_n) +
                    " training frames match; both must be at least 1");
      std::string ids;
      for (const auto& id : config.inner_frames) ids += (ids.empty() ? "" : ", ") + id;
      inner_text = "inner frames " + ids + " (" + std::to_string(inner_n) + " frames, held out whole) choose the epoch; " +
                   std::to_string(train_n) + " training frames left";
    } else {
      if (split.regions.empty())
        throw Error("lidar-train: --early-stop: needs a guarded region split (--split guarded) or frames:..., got --split " + config.split);
      inner = data::inner_split(split, half_width, cols, config.inner_columns);
      train_split = data::with_inner(split, *inner);
      const auto roles = train_split.roles(cols);
      const long b = std::lround(inner->regions[0].first * cols), e = std::lround(inner->regions[0].second * cols);
      char text[400];
      std::snprintf(text, sizeof text,
                    "inner region [%ld, %ld) (%d columns, every scan) chooses the epoch; guard bands [%ld, %ld) (the scored "
                    "region's) and [%ld, %ld) (its own), each %d columns; %ld training columns left of %d",
                    b, e, config.inner_columns, (b - inner->guard_columns + cols) % cols, b, e, (e + inner->guard_columns) % cols,
                    inner->guard_columns, static_cast<long>(std::count(roles.begin(), roles.end(), data::kTrain)), cols);
      inner_text = text;
    }
    if (config.progress && dist.root()) std::fprintf(stderr, "lidar-train: early stopping: %s\n", inner_text.c_str());
    if (config.resume && !config.out.empty() && std::filesystem::exists(config.out))
      throw Error("lidar-train: --early-stop with --resume: not supported (the inner losses of the epochs before are not in the checkpoint)");
  }

  // Frames are read per step (frame_batches.h); the cells a frame trains on follow the split.
  if (config.train_also.size() >= train_sets.size())
    throw Error("lidar-train: --train-also needs --data to validate on");
  const int split_sets = static_cast<int>(train_sets.size() - config.train_also.size());
  const std::vector<const data::FrameSource*> scored(train_sets.begin(), train_sets.begin() + split_sets);
  const TrainingFrames frames(train_sets, config.encoder, sector_split ? std::optional(train_split) : std::nullopt, split_sets);
  const int num_frames = frames.size();
  // Rolling or mirroring the azimuth would contradict channels that encode direction.
  bool roll = config.augment_roll, mirror = config.augment_mirror;
  for (const auto& c : config.encoder.channels)
    if ((c == "azimuth" || c == "x" || c == "y") && (roll || mirror)) {
      if (dist.root())
        std::fprintf(stderr, "lidar-train: channel '%s' encodes direction: azimuth roll and mirror are off\n", c.c_str());
      roll = mirror = false;
    }
  const int width = config.crop_columns > 0 ? std::min(config.crop_columns, cols) : cols;

  // --- model, optimizer, resume ----------------------------------------------------------------
  auto model_ptr = std::make_shared<nn::UNet>(arch);
  nn::UNet& model = *model_ptr;
  model.init(config.seed);
  nn::OptimizerConfig opt_config;
  opt_config.kind = "adam";
  opt_config.lr = config.lr;
  nn::Optimizer optimizer(opt_config, model.params().size());

  const std::int64_t steps_per_epoch =
      config.steps_per_epoch > 0 ? config.steps_per_epoch : (num_frames + config.batch - 1) / config.batch;
  const std::int64_t total_steps = steps_per_epoch * config.epochs;
  std::int64_t step = 0;
  const bool checkpoints = !config.out.empty();
  if (config.resume && checkpoints && std::filesystem::exists(config.out)) {
    const nn::Checkpoint meta = nn::read_checkpoint_meta(config.out);
    if (!(meta.unet == arch))
      throw input_error(config.out.string(), "/config/unet", "architecture differs from the requested one");
    const auto enc = meta.attributes.find("encoder");
    if (enc == meta.attributes.end() || enc->second != config.encoder.to_json())
      throw input_error(config.out.string(), "/config/encoder", "input encoding differs from the requested one");
    check_resume_settings(config, meta);
    nn::load_checkpoint(config.out, model, &optimizer);
    step = meta.state.step;
    if (dist.root())
      std::fprintf(stderr, "lidar-train: resuming %s at step %lld (epoch %lld)\n", config.out.c_str(),
                 static_cast<long long>(step), static_cast<long long>(step / steps_per_epoch));
  }

  nn::Checkpoint meta;
  meta.unet = arch;
  meta.attributes["encoder"] = config.encoder.to_json();
  meta.attributes["beam_layout"] = train_sets[0]->header().layout.to_json();
  meta.attributes["lambda"] = std::to_string(config.lambda);
  meta.attributes["seed"] = std::to_string(config.seed);
  meta.attributes["loss"] = config.lookup_base ? "masked_mse of (lookup base + network) + lambda * sum(w^2); lookup fitted on the training cells"
                           : config.row_affine ? "masked_mse + lambda * (sum(w^2) + sum((row gain - 1)^2) + sum(row offset^2))"
                                             : "masked_mse + lambda * sum(w^2), weights only";
  meta.attributes["train_config"] = describe_config(config);
  meta.attributes["receptive_field_half_width"] = std::to_string(half_width);
  meta.attributes["split"] = sector_split ? split.describe(cols) : "separate validation dataset";
  if (inner) meta.attributes["early_stop"] = inner_text;
  auto save = [&](std::int64_t at_step) {
    meta.state.step = at_step;
    meta.state.epoch = at_step / steps_per_epoch;
    meta.state.rng = "counter-based: seed " + std::to_string(config.seed) + ", step " + std::to_string(at_step);
    if (checkpoints && dist.root()) nn::save_checkpoint(config.out, model, &optimizer, meta);  // rank 0 alone writes
  };

  auto validate = [&]() {
    std::vector<data::Metrics> parts;
    // Frame by frame, the next one read while the model predicts this one. Under MPI every rank
    // scores every frame: the same weights give the same figures on each, with no reduction.
    if (val_set) parts = validate_frames(model, config.encoder, {val_set}, all_validation(), prefetch);
    else parts = validate_frames(model, config.encoder, scored, split, prefetch);
    return merge(parts);
  };

  TrainResult result;
  result.inner_region = inner_text;
  EarlyStop stopper(config.patience);
  std::vector<float> best_weights;
  if (config.lookup_base && step == 0) {
    // Every rank fits the same table from the same frames (no communication needed).
    // On every training column of the split (with early stopping the inner region's too), so the
    // table is the same with or without it; the scored regions and their guards never.
    const TrainingFrames table_frames(train_sets, config.encoder, sector_split ? std::optional(split) : std::nullopt,
                                      split_sets);
    const LookupFit fit = fit_lookup_base(arch.lookup, table_frames, cols,
                                          config.lookup_form == "classes" ? BeamFit::loop : BeamFit::mean);
    set_lookup_base(model, fit);
    result.lookup_validation = validate();  // the head starts at 0: this is the table alone
    if (config.progress && dist.root())
      std::fprintf(stderr, "lidar-train: lookup base fitted on %ld training cells; alone: validation MAE %.4f RMSE %.4f (%ld cells)\n",
                   fit.cells, result.lookup_validation->mae, result.lookup_validation->rmse, result.lookup_validation->cells);
  }

  // Every rank is set up (data read, model built, checkpoint loaded) before the first step.
  dist.agree("");
  set_up = true;

  // --- the loop -------------------------------------------------------------------------------
  // This rank's part of the global batch: all of it in one process.
  const BatchShare share = batch_share(config.batch, dist.rank(), dist.size());
  nn::Tensor pred, d_pred;
  ProgressBar bar("train", total_steps, config.progress && dist.root());
  double epoch_loss = 0;
  int epoch_steps = 0;
  auto epoch_start = std::chrono::steady_clock::now();
  // Each step's batch is read and assembled on a background thread while the previous step
  // computes; which frames, crops and mirrors is a pure function of (seed, epoch, step).
  const SamplePlan plan{num_frames, steps_per_epoch, config.batch, cols, width, roll, mirror, config.seed};
  struct Batch {
    nn::Tensor x, y, m;
  };
  Prefetcher<Batch> batches(
      [&](std::int64_t k, Batch& out) {
        // Only this rank's samples are read: the others' frames never leave their files.
        out.x.resize({share.count, in_channels, rows, width});
        out.y.resize({share.count, 1, rows, width});
        out.m.resize({share.count, 1, rows, width});
        const std::vector<Sample> samples = step_samples(plan, k);
        for (int b = share.begin; b < share.begin + share.count; ++b)
          frames.fill(samples[static_cast<std::size_t>(b)], out.x, out.y, out.m, b - share.begin);
      },
      step, total_steps, prefetch);
  while (step < total_steps) {
    const std::int64_t epoch = step / steps_per_epoch;
    const Batch* batch = nullptr;
    std::string read_error;  // under MPI a rank's bad frame is agreed on, not an abort
    try {
      batch = &batches.next();
    } catch (const std::exception& e) {
      if (!dist.active()) throw;
      read_error = *e.what() ? e.what() : "unknown error";
    }
    model.params().zero_grads();
    double data_loss = 0, l2 = 0;
    bool stop = false;
    if (!dist.active()) {
      model.forward(batch->x, pred);
      data_loss = nn::masked_mse(pred, batch->y, batch->m, &d_pred).data;
      l2 = nn::l2_penalty(model.params(), config.lambda, true);
      model.backward(d_pred);
    } else {
      static const nn::Tensor none;
      data_loss = data_parallel_gradients(model, batch ? batch->x : none, batch ? batch->y : none,
                                          batch ? batch->m : none, read_error, pred, d_pred, stop);
      l2 = nn::l2_penalty(model.params(), config.lambda, true);  // once, on the summed gradients
    }
    optimizer.set_lr(learning_rate(config, step, total_steps));
    optimizer.step(model.params());
    ++step;
    epoch_loss += data_loss + l2;
    ++epoch_steps;
    char status[96];
    std::snprintf(status, sizeof status, "epoch %lld loss %.5f", static_cast<long long>(epoch + 1), data_loss + l2);
    bar.update(step, status);

    const bool epoch_done = step % steps_per_epoch == 0;
    if (epoch_done) {
      EpochReport report;
      report.epoch = static_cast<int>(step / steps_per_epoch);
      report.step = step;
      report.train_loss = epoch_loss / std::max(1, epoch_steps);
      report.samples = epoch_steps * config.batch;
      const auto validation_start = std::chrono::steady_clock::now();
      report.train_seconds = std::chrono::duration<double>(validation_start - epoch_start).count();
      if (inner) {
        report.inner = merge(validate_frames(model, config.encoder, scored, *inner, prefetch));
        if (stopper.add(report.inner->mae))
          best_weights.assign(model.params().values(), model.params().values() + model.params().size());
      } else {
        report.validation = validate();
      }
      report.validation_seconds =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - validation_start).count();
      epoch_loss = 0;
      epoch_steps = 0;
      result.epochs.push_back(report);
      // Rank 0 writes the checkpoint and the caller's log; a failure there stops every rank.
      agreed([&] {
        save(step);
        if (on_epoch && dist.root()) on_epoch(report);
      });
      epoch_start = std::chrono::steady_clock::now();
    }
    // Several ranks stop together, at the step where any of them was asked to.
    if (dist.active() ? stop : stop_requested().load()) {
      if (!epoch_done) agreed([&] { save(step); });
      result.interrupted = true;
      break;
    }
    if (inner && epoch_done && stopper.exhausted()) break;  // every rank saw the same inner losses
  }
  if (inner && !result.interrupted && stopper.best_epoch() > 0) {
    // The chosen epoch's weights, scored once on the validation regions; the checkpoint then
    // holds them (weights only: the optimizer state belongs to the last step).
    std::copy(best_weights.begin(), best_weights.end(), model.params().values());
    result.chosen_epoch = stopper.best_epoch();
    if (config.shrink_residual) {
      // The inner region alone decides; the scored regions are measured after (the unscaled
      // weights too, for the before/after report: neither figure feeds back into the choice).
      result.unscaled_validation = validate();
      const ResidualShrink shrink = choose_residual_scale(
          model, [&] { return merge(validate_frames(model, config.encoder, scored, *inner, prefetch)).mae; });
      result.residual_scale = shrink.scale;
      result.residual_scale_inner_mae = shrink.inner_mae;
      inner_text += "; residual scaled by " + std::to_string(shrink.scale).substr(0, 4) + " (chosen on the inner region)";
    }
    result.chosen_validation = validate();
    meta.state.step = static_cast<std::int64_t>(result.chosen_epoch) * steps_per_epoch;
    meta.state.epoch = result.chosen_epoch;
    meta.attributes["early_stop"] = inner_text + "; chosen epoch " + std::to_string(result.chosen_epoch);
    agreed([&] {
      if (checkpoints && dist.root()) nn::save_checkpoint(config.out, model, nullptr, meta);
    });
  }
  if (!result.interrupted) {
    bar.finish();
    if (config.export_weights) {
      if (!inner) meta.state.step = step, meta.state.epoch = step / steps_per_epoch;
      agreed([&] {
        if (dist.root()) nn::save_checkpoint(*config.export_weights, model, nullptr, meta);
      });
    }
  }
  result.steps = step;
  result.model = model_ptr;
  if (result.chosen_epoch == 0) meta.state.step = step, meta.state.epoch = step / steps_per_epoch;
  result.meta = meta;
  return result;
}

}  // namespace

}  // namespace lidarsim::train
