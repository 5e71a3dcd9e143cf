#include "train/training_run.h"

#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <numeric>
#include <optional>
#include <string>

#include "common/error.h"
#include "common/progress.h"
#include "nn/checkpoint.h"
#include "nn/heads.h"
#include "nn/loss.h"
#include "nn/optim.h"
#include "nn/receptive_field.h"
#include "train/data_parallel.h"
#include "train/distributed.h"
#include "train/early_stop.h"
#include "train/frame_batches.h"
#include "train/lookup_fit.h"
#include "train/prefetcher.h"
#include "train/residual_shrink.h"
#include "train/run_settings.h"
#include "train/spread_metrics.h"
#include "train/spread_step.h"

namespace lidarsim::train {
namespace {

// The /config attribute holding the run's kernel plan (nn/kernel_plan.h to_json).
constexpr const char* kPlanAttribute = "kernel_plan";

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

int split_sets_of(const std::vector<const data::FrameSource*>& sets, const TrainConfig& c) {
  return static_cast<int>(sets.size() - std::min(sets.size(), c.train_also.size()));
}

// This rank's part of one step's batch.
struct Batch {
  nn::Tensor x, y, m;
};

// The run's state, filled by its steps in the order train_on_ranks calls them; a step reads only
// what the steps before it filled.
class TrainingRun {
 public:
  TrainingRun(const TrainConfig& config, LookupForm lookup_form,
              const std::vector<const data::FrameSource*>& train_sets, const data::FrameSource* val_set);
  void plan_early_stop();
  void plan_frames();
  void build_model();
  void start_from_lookup_base();
  void loop(const std::function<void(const EpochReport&)>& on_epoch);
  void keep_chosen_epoch();
  TrainResult finish();

 private:
  void check_grids();
  void check_intensity_scales() const;
  void hold_out_inner_frames();
  void hold_out_inner_of_training_sets();
  void hold_out_inner_columns();
  void calibrate_spread_on_inner();
  void resume_from_checkpoint();
  nn::Checkpoint checkpoint_meta() const;
  void save(std::int64_t at_step);
  void record_plan();  // the model's kernel plan into meta (every checkpoint of the run carries it)
  data::Metrics validate();
  SpreadMetrics validate_spread_now(const data::SectorSplit* region);
  double train_step(Prefetcher<Batch>& batches, bool& stop);
  double spread_step(const Batch& batch, double& l2);  // sets l2 to the L2 penalty
  EpochReport end_epoch(double epoch_loss, int epoch_steps, std::chrono::steady_clock::time_point epoch_start);

  const TrainConfig& config;
  const LookupForm lookup_form;
  Distributed& dist = Distributed::world();
  const std::vector<const data::FrameSource*>& train_sets;
  const data::FrameSource* val_set;
  bool prefetch = true;
  // Data and split.
  int rows = 0, cols = 0;
  bool sector_split = false;
  int in_channels = 0;
  nn::UNetConfig arch;
  int half_width = 0;
  bool spread = false;  // a spread head after the mean (--heads)
  data::SectorSplit split;
  // Early stopping: the network trains outside the inner region and its guard band too.
  std::optional<data::SectorSplit> inner;
  data::SectorSplit train_split;
  std::string inner_text;
  // Frames.
  int split_sets = 0;
  std::vector<const data::FrameSource*> scored;
  std::optional<TrainingFrames> frames;
  int num_frames = 0;
  bool roll = false, mirror = false;
  int width = 0;
  // Model, optimizer, steps.
  std::shared_ptr<nn::UNet> model;
  std::optional<nn::Optimizer> optimizer;
  std::int64_t steps_per_epoch = 0, total_steps = 0, step = 0;
  bool checkpoints = false;
  nn::Checkpoint meta;
  // Results.
  TrainResult result;
  EarlyStop stopper;
  std::vector<float> best_weights;
  nn::Tensor pred, d_pred;
  SpreadStepBuffers spread_buffers;
  std::optional<ProgressBar> bar;
};

// --- data: headers now, frames when a step needs them ------------------------------------------
TrainingRun::TrainingRun(const TrainConfig& config, LookupForm lookup_form,
                         const std::vector<const data::FrameSource*>& train_sets, const data::FrameSource* val_set)
    : config(config), lookup_form(lookup_form), train_sets(train_sets), val_set(val_set), stopper(config.patience) {
  if (train_sets.empty()) throw Error("lidar-train: no training data given");
  validate_settings(config);
  omp_set_num_threads(config.threads);
  // Reading on a background thread needs an HDF5 built thread-safe (checkpoints are written meanwhile).
  prefetch = config.prefetch;
  for (const data::FrameSource* set : train_sets) prefetch = prefetch && set->reads_overlap_other_hdf5();
  if (val_set) prefetch = prefetch && val_set->reads_overlap_other_hdf5();

  check_grids();
  check_intensity_scales();
  sector_split = val_set == nullptr;
  in_channels = config.encoder.input_channels();
  arch = nn::UNetConfig{in_channels, 1, config.base, config.depth, config.row_affine ? rows : 0};
  // "mean" alone is the single-output model without heads: checkpoint format 1, which builds that
  // predate format 2 still load (they refuse format 2's heads).
  const std::vector<nn::HeadKind> heads = nn::parse_heads(config.heads, "lidar-train: --heads");
  spread = heads.size() > 1;
  if (spread) {
    arch.out_channels = static_cast<int>(heads.size());
    arch.heads = heads;
  }
  if (config.lookup_base) arch.lookup = lookup_base_config(config.encoder, rows);
  half_width = nn::receptive_field_half_width(arch);
  split = data::parse_split(config.split, half_width, cols);
  if (sector_split && split.validation_frames.empty() && !split.regions.empty() && split.guard_columns < 2 * half_width)
    throw Error("lidar-train: --split " + config.split + ": guard bands of " + std::to_string(split.guard_columns) +
                " columns are narrower than twice the model's receptive-field half-width (" +
                std::to_string(half_width) + " columns): validation would leak");
  if (sector_split && config.progress && dist.root())
    std::fprintf(stderr, "lidar-train: receptive field half-width %d columns; split: %s\n", half_width,
                 split.describe(cols).c_str());
  train_split = split;
}

void TrainingRun::check_grids() {
  rows = train_sets[0]->rows(), cols = train_sets[0]->cols();
  for (std::size_t i = 0; i < train_sets.size(); ++i)
    if (train_sets[i]->rows() != rows || train_sets[i]->cols() != cols)
      throw input_error(train_sets[i]->name(), "/pgm", "grid " + std::to_string(train_sets[i]->rows()) + " x " +
                                                  std::to_string(train_sets[i]->cols()) + " differs from " +
                                                  std::to_string(rows) + " x " + std::to_string(cols));
}

// Datasets whose recorded intensity scales differ (data/intensity_scale.h) are not mixed unless
// asked; those without a recorded scale (older files) are not compared.
void TrainingRun::check_intensity_scales() const {
  std::vector<std::pair<std::string, data::IntensityScale>> named;
  for (const data::FrameSource* set : train_sets) named.emplace_back(set->name(), set->header().intensity_scale);
  if (val_set) named.emplace_back(val_set->name(), val_set->header().intensity_scale);
  const std::string conflict = data::intensity_scale_conflict(named);
  if (conflict.empty()) return;
  if (!config.mix_intensity_scales)
    throw Error("lidar-train: intensity scales differ: " + conflict +
                ". Their 0-1 targets measure different things; train on one scale, or pass --mix-intensity-scales");
  if (config.progress && dist.root())
    std::fprintf(stderr, "lidar-train: mixing intensity scales (--mix-intensity-scales): %s\n", conflict.c_str());
}

// --- early stopping: the inner hold-out that chooses the epoch ---------------------------------
void TrainingRun::plan_early_stop() {
  if (!config.early_stop) return;
  // Frames name places; a column split has no frame to hold out, so the option would be ignored.
  if ((!sector_split || split.validation_frames.empty()) && !config.inner_frames.empty())
    throw Error("lidar-train: --inner-frames: needs --split frames:... (not --val); with a column split the inner region is columns (--inner-columns)");
  if (!sector_split)
    hold_out_inner_of_training_sets();
  else if (!split.validation_frames.empty())
    hold_out_inner_frames();
  else
    hold_out_inner_columns();
  if (config.progress && dist.root()) std::fprintf(stderr, "lidar-train: early stopping: %s\n", inner_text.c_str());
  if (config.resume && !config.out.empty() && std::filesystem::exists(config.out))
    throw Error("lidar-train: --early-stop with --resume: not supported (the inner losses of the epochs before are not in the checkpoint)");
}

// With a frame hold-out: the inner set is the named training frames (other places), held out whole.
void TrainingRun::hold_out_inner_frames() {
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
}

// With a separate validation set (--val: another place) every column of --data trains, so the
// inner region is the guarded split's (the same columns, so the same kind of view), with its guard
// band of 2 h on both sides; the --val set is read once, for the chosen epoch.
void TrainingRun::hold_out_inner_of_training_sets() {
  inner = data::inner_split(data::guarded_split(half_width, cols), half_width, cols, config.inner_columns);
  train_split = *inner;
  const long b = std::lround(inner->regions[0].first * cols), e = std::lround(inner->regions[0].second * cols);
  inner_text = "inner region [" + std::to_string(b) + ", " + std::to_string(e) + ") of every --data scan chooses the epoch; guard bands of " +
               std::to_string(inner->guard_columns) + " columns on both sides; the --val set is scored once, for the chosen epoch";
}

// With a guarded region split: an inner region of columns with its own guard band.
void TrainingRun::hold_out_inner_columns() {
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

// --- frames: read per step (frame_batches.h); the cells a frame trains on follow the split -----
void TrainingRun::plan_frames() {
  if (config.train_also.size() >= train_sets.size())
    throw Error("lidar-train: --train-also needs --data to validate on");
  split_sets = static_cast<int>(train_sets.size() - config.train_also.size());
  scored.assign(train_sets.begin(), train_sets.begin() + split_sets);
  frames.emplace(train_sets, config.encoder, sector_split || inner ? std::optional(train_split) : std::nullopt, split_sets);
  num_frames = frames->size();
  // Rolling or mirroring the azimuth would contradict channels that encode direction.
  roll = config.augment_roll, mirror = config.augment_mirror;
  for (const auto& c : config.encoder.channels)
    if ((c == "azimuth" || c == "x" || c == "y") && (roll || mirror)) {
      if (dist.root())
        std::fprintf(stderr, "lidar-train: channel '%s' encodes direction: azimuth roll and mirror are off\n", c.c_str());
      roll = mirror = false;
    }
  width = config.crop_columns > 0 ? std::min(config.crop_columns, cols) : cols;
}

// --- model, optimizer, resume ------------------------------------------------------------------
void TrainingRun::build_model() {
  model = std::make_shared<nn::UNet>(arch);
  model->init(config.seed);
  model->set_kernel_plan(nn::KernelPlan(config.kernels));
  nn::OptimizerConfig opt_config;
  opt_config.kind = nn::OptimizerKind::Adam;
  opt_config.lr = config.lr;
  optimizer.emplace(opt_config, model->params().size());

  steps_per_epoch =
      config.steps_per_epoch > 0 ? config.steps_per_epoch : (num_frames + config.batch - 1) / config.batch;
  total_steps = steps_per_epoch * config.epochs;
  step = 0;
  checkpoints = !config.out.empty();
  if (config.resume && checkpoints && std::filesystem::exists(config.out)) resume_from_checkpoint();
  meta = checkpoint_meta();
}

void TrainingRun::resume_from_checkpoint() {
  const nn::Checkpoint stored = nn::read_checkpoint_meta(config.out);
  if (!(stored.unet == arch))
    throw input_error(config.out.string(), "/config/unet", "architecture differs from the requested one");
  const auto enc = stored.attributes.find("encoder");
  if (enc == stored.attributes.end() || enc->second != config.encoder.to_json())
    throw input_error(config.out.string(), "/config/encoder", "input encoding differs from the requested one");
  check_resume_settings(config, stored);
  nn::load_checkpoint(config.out, *model, &*optimizer);
  // The kernels the run took so far, held (checkpoints before the plan: config.kernels).
  if (const auto plan = stored.attributes.find(kPlanAttribute); plan != stored.attributes.end())
    model->set_kernel_plan(nn::KernelPlan::from_json(plan->second, config.out.string() + ": /config/" + kPlanAttribute));
  step = stored.state.step;
  if (dist.root())
    std::fprintf(stderr, "lidar-train: resuming %s at step %lld (epoch %lld)\n", config.out.c_str(),
                 static_cast<long long>(step), static_cast<long long>(step / steps_per_epoch));
}

// What every checkpoint of this run records besides the weights (/config attributes).
nn::Checkpoint TrainingRun::checkpoint_meta() const {
  nn::Checkpoint m;
  m.unet = arch;
  m.attributes["encoder"] = config.encoder.to_json();
  m.attributes["beam_layout"] = train_sets[0]->header().layout.to_json();
  m.attributes["lambda"] = std::to_string(config.lambda);
  m.attributes["seed"] = std::to_string(config.seed);
  m.attributes["loss"] = config.lookup_base ? "masked_mse of (lookup base + network) + lambda * sum(w^2); lookup fitted on the training cells"
                         : config.row_affine ? "masked_mse + lambda * (sum(w^2) + sum((row gain - 1)^2) + sum(row offset^2))"
                                             : "masked_mse + lambda * sum(w^2), weights only";
  if (spread)
    m.attributes["loss"] += "; head 1 (" + std::string(nn::head_name(arch.heads[1])) +
                            "): masked NLL of the measured intensity around the mean; trains only its own output parameters";
  m.attributes["train_config"] = describe_config(config);
  m.attributes["receptive_field_half_width"] = std::to_string(half_width);
  m.attributes["split"] = sector_split ? split.describe(cols) : "separate validation dataset";
  if (inner) m.attributes["early_stop"] = inner_text;
  return m;
}

void TrainingRun::record_plan() { meta.attributes[kPlanAttribute] = model->kernel_plan().to_json(); }

void TrainingRun::save(std::int64_t at_step) {
  record_plan();
  meta.state.step = at_step;
  meta.state.epoch = at_step / steps_per_epoch;
  meta.state.rng = "counter-based: seed " + std::to_string(config.seed) + ", step " + std::to_string(at_step);
  if (checkpoints && dist.root()) nn::save_checkpoint(config.out, *model, &*optimizer, meta);  // rank 0 alone writes
}

data::Metrics TrainingRun::validate() {
  std::vector<data::Metrics> parts;
  // Frame by frame, the next one read while the model predicts this one. Under MPI every rank
  // scores every frame: the same weights give the same figures on each, with no reduction.
  if (val_set) parts = validate_frames(*model, config.encoder, {val_set}, all_validation(), prefetch);
  else parts = validate_frames(*model, config.encoder, scored, split, prefetch);
  return merge(parts);
}

// The spread head's NLL and interval coverage on `region` of the scored sets (null: the scored
// validation cells, or the whole separate validation set).
SpreadMetrics TrainingRun::validate_spread_now(const data::SectorSplit* region) {
  if (region) return validate_spread(*model, config.encoder, scored, *region);
  if (val_set) return validate_spread(*model, config.encoder, {val_set}, all_validation());
  return validate_spread(*model, config.encoder, scored, split);
}

// --- the lookup base: fitted once, before the first step ---------------------------------------
void TrainingRun::start_from_lookup_base() {
  result.inner_region = inner_text;
  if (!(config.lookup_base && step == 0)) return;
  // Every rank fits the same table from the same frames (no communication needed).
  // On every training column of the split (with early stopping the inner region's too), so the
  // table is the same with or without it; the scored regions and their guards never.
  const TrainingFrames table_frames(train_sets, config.encoder, sector_split ? std::optional(split) : std::nullopt,
                                    split_sets);
  const LookupFit fit = fit_lookup_base(arch.lookup, table_frames, cols,
                                        lookup_form == LookupForm::classes ? BeamFit::loop : BeamFit::mean);
  set_lookup_base(*model, fit);
  result.lookup_validation = validate();  // the head starts at 0: this is the table alone
  if (config.progress && dist.root())
    std::fprintf(stderr, "lidar-train: lookup base fitted on %ld training cells; alone: validation MAE %.4f RMSE %.4f (%ld cells)\n",
                 fit.cells, result.lookup_validation->mae, result.lookup_validation->rmse, result.lookup_validation->cells);
}

// --- the loop ----------------------------------------------------------------------------------
void TrainingRun::loop(const std::function<void(const EpochReport&)>& on_epoch) {
  // This rank's part of the global batch: all of it in one process.
  const BatchShare share = batch_share(config.batch, dist.rank(), dist.size());
  bar.emplace("train", total_steps, config.progress && dist.root());
  double epoch_loss = 0;
  int epoch_steps = 0;
  auto epoch_start = std::chrono::steady_clock::now();
  // Each step's batch is read and assembled on a background thread while the previous step
  // computes; which frames, crops and mirrors is a pure function of (seed, epoch, step).
  const SamplePlan plan{num_frames, steps_per_epoch, config.batch, cols, width, roll, mirror, config.seed};
  Prefetcher<Batch> batches(
      [&](std::int64_t k, Batch& out) {
        // Only this rank's samples are read: the others' frames never leave their files.
        out.x.resize({share.count, in_channels, rows, width});
        out.y.resize({share.count, 1, rows, width});
        out.m.resize({share.count, 1, rows, width});
        const std::vector<Sample> samples = step_samples(plan, k);
        for (int b = share.begin; b < share.begin + share.count; ++b)
          frames->fill(samples[static_cast<std::size_t>(b)], out.x, out.y, out.m, b - share.begin);
      },
      step, total_steps, prefetch);
  while (step < total_steps) {
    const std::int64_t epoch = step / steps_per_epoch;
    bool stop = false;
    const double loss = train_step(batches, stop);
    epoch_loss += loss;
    ++epoch_steps;
    char status[96];
    std::snprintf(status, sizeof status, "epoch %lld loss %.5f", static_cast<long long>(epoch + 1), loss);
    bar->update(step, status);

    const bool epoch_done = step % steps_per_epoch == 0;
    if (epoch_done) {
      const EpochReport report = end_epoch(epoch_loss, epoch_steps, epoch_start);
      epoch_loss = 0;
      epoch_steps = 0;
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
}

// One step: this rank's batch, the gradients (summed over the ranks under MPI), the optimizer
// step. Returns the step's loss (data + L2); `stop` is set when any rank was asked to stop.
double TrainingRun::train_step(Prefetcher<Batch>& batches, bool& stop) {
  const Batch* batch = nullptr;
  std::string read_error;  // under MPI a rank's bad frame is agreed on, not an abort
  try {
    batch = &batches.next();
  } catch (const std::exception& e) {
    if (!dist.active()) throw;
    read_error = *e.what() ? e.what() : "unknown error";
  }
  model->params().zero_grads();
  double data_loss = 0, l2 = 0;
  if (!dist.active()) {
    if (!spread) {
      model->forward(batch->x, pred);
      data_loss = nn::masked_mse(pred, batch->y, batch->m, &d_pred).data;
      l2 = nn::l2_penalty(model->params(), config.lambda, true);
      model->backward(d_pred);
    } else {
      data_loss = spread_step(*batch, l2);
    }
  } else {
    static const nn::Tensor none;
    data_loss = data_parallel_gradients(*model, batch ? batch->x : none, batch ? batch->y : none,
                                        batch ? batch->m : none, read_error, pred, d_pred, stop);
    l2 = nn::l2_penalty(model->params(), config.lambda, true);  // once, on the summed gradients
  }
  optimizer->set_lr(learning_rate(config, step, total_steps));
  optimizer->step(model->params());
  ++step;
  return data_loss + l2;
}

double TrainingRun::spread_step(const Batch& batch, double& l2) {
  if (step == 0) start_spread_at(*model, batch.y, batch.m);
  return spread_step_gradients(*model, arch.heads, batch.x, batch.y, batch.m, config.spread_weight, config.lambda, &l2,
                               spread_buffers);
}

// The epoch's report: its mean loss and timing, and its validation (with early stopping the inner
// hold-out, whose best epoch's weights are kept).
EpochReport TrainingRun::end_epoch(double epoch_loss, int epoch_steps,
                                   std::chrono::steady_clock::time_point epoch_start) {
  EpochReport report;
  report.epoch = static_cast<int>(step / steps_per_epoch);
  report.step = step;
  report.train_loss = epoch_loss / std::max(1, epoch_steps);
  report.samples = epoch_steps * config.batch;
  const auto validation_start = std::chrono::steady_clock::now();
  report.train_seconds = std::chrono::duration<double>(validation_start - epoch_start).count();
  if (inner) {
    report.inner = merge(validate_frames(*model, config.encoder, scored, *inner, prefetch));
    if (stopper.add(report.inner->mae))
      best_weights.assign(model->params().values(), model->params().values() + model->params().size());
  } else {
    report.validation = validate();
  }
  if (spread) report.spread = validate_spread_now(inner ? &*inner : nullptr);
  report.validation_seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - validation_start).count();
  result.epochs.push_back(report);
  return report;
}

// --- the end -----------------------------------------------------------------------------------
// With early stopping: the chosen epoch's weights, scored once on the validation regions; the
// checkpoint then holds them (weights only: the optimizer state belongs to the last step).
void TrainingRun::keep_chosen_epoch() {
  if (!(inner && !result.interrupted && stopper.best_epoch() > 0)) return;
  std::copy(best_weights.begin(), best_weights.end(), model->params().values());
  result.chosen_epoch = stopper.best_epoch();
  if (config.shrink_residual) {
    // The inner region alone decides; the scored regions are measured after (the unscaled
    // weights too, for the before/after report: neither figure feeds back into the choice).
    result.unscaled_validation = validate();
    const ResidualShrink shrink = choose_residual_scale(
        *model, [&] { return merge(validate_frames(*model, config.encoder, scored, *inner, prefetch)).mae; });
    result.residual_scale = shrink.scale;
    result.residual_scale_inner_mae = shrink.inner_mae;
    inner_text += "; residual scaled by " + std::to_string(shrink.scale).substr(0, 4) + " (chosen on the inner region)";
  }
  result.chosen_validation = validate();
  if (spread) calibrate_spread_on_inner();
  meta.state.step = static_cast<std::int64_t>(result.chosen_epoch) * steps_per_epoch;
  meta.state.epoch = result.chosen_epoch;
  meta.attributes["early_stop"] = inner_text + "; chosen epoch " + std::to_string(result.chosen_epoch);
  record_plan();
  agreed([&] {
    if (checkpoints && dist.root()) nn::save_checkpoint(config.out, *model, nullptr, meta);
  });
}

// The spread's scale factor, fitted on the inner region: cells the mean never trained on (its
// guard band keeps the training cells' inputs away) and never scored (the scored region's guard
// band keeps them apart), so the factor is chosen without the scored cells. The scored figures
// before and after are measured once, for the report.
void TrainingRun::calibrate_spread_on_inner() {
  result.uncalibrated_spread = validate_spread_now(nullptr);
  result.spread_calibration_cells = calibrate_spread(*model, config.encoder, scored, *inner);
  result.spread_scale = model->config().spread_scale;
  result.chosen_spread = validate_spread_now(nullptr);
  // Then the residual's shape with that scale, on the same cells (train/spread_metrics.h).
  const nn::SpreadResidual residual = fit_spread_residual(*model, config.encoder, scored, *inner);
  char text[240];
  std::snprintf(text, sizeof text,
                "spread scale x%.4f: the likelihood's best factor on the inner region (%ld cells); residual quantiles "
                "(%d per bin, %d bins of the mean) fitted there; targets' grid step %g",
                *result.spread_scale, result.spread_calibration_cells->cells, residual.levels, residual.bins(),
                residual.target_step);
  meta.attributes["spread_calibration"] = text;
}

TrainResult TrainingRun::finish() {
  record_plan();
  if (!result.interrupted) {
    bar->finish();
    if (config.export_weights) {
      if (!inner) meta.state.step = step, meta.state.epoch = step / steps_per_epoch;
      agreed([&] {
        if (dist.root()) nn::save_checkpoint(*config.export_weights, *model, nullptr, meta);
      });
    }
  }
  result.steps = step;
  result.model = model;
  if (result.chosen_epoch == 0) meta.state.step = step, meta.state.epoch = step / steps_per_epoch;
  result.meta = meta;
  return result;
}

}  // namespace

TrainResult train_on_ranks(const TrainConfig& config, LookupForm lookup_form,
                           const std::vector<const data::FrameSource*>& train_sets, const data::FrameSource* val_set,
                           const std::function<void(const EpochReport&)>& on_epoch, bool& set_up) {
  TrainingRun run(config, lookup_form, train_sets, val_set);
  run.plan_early_stop();
  run.plan_frames();
  run.build_model();
  run.start_from_lookup_base();
  // Every rank is set up (data read, model built, checkpoint loaded) before the first step.
  Distributed::world().agree("");
  set_up = true;
  run.loop(on_epoch);
  run.keep_chosen_epoch();
  return run.finish();
}

}  // namespace lidarsim::train
