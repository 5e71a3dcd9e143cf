#pragma once
// The training loop behind `lidar-train`: a UNet learns measured intensity from Polar Grid Map
// datasets (data/dataset.h) with masked MSE + L2 on the weights.
//
// Randomness is a pure function of (seed, epoch, step): the frame order of an epoch comes from
// (seed, epoch), each step's augmentation from (seed, step). A checkpoint therefore only needs
// the step count to resume, and a resumed run ends with the same weights, bit for bit, as an
// uninterrupted one (same thread count).
//
// Frames are read from the files when a step needs them (data::FrameSource, on a prefetching
// thread one step ahead: train/frame_batches.h, train/prefetcher.h) and validated one at a time,
// so memory holds a few frames whatever the dataset's length.
#include <atomic>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <iterator>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "data/baselines.h"
#include "data/dataset.h"
#include "data/frame_source.h"
#include "data/split.h"
#include "nn/checkpoint.h"
#include "nn/unet.h"
#include "pgm/encoder.h"

namespace lidarsim::train {

// The lookup base's form (TrainConfig::lookup_form), by its spelling on the command line and in
// train_config: "groups" or "classes".
enum class LookupForm { groups, classes };
inline constexpr const char* kLookupFormNames[] = {"groups", "classes"};
static_assert(std::size(kLookupFormNames) == static_cast<std::size_t>(LookupForm::classes) + 1,
              "kLookupFormNames: one name per LookupForm");
// The form a spelling names; anything else throws lidarsim::Error
// "lidar-train: --lookup-base: must be groups or classes, got \"<name>\"".
LookupForm parse_lookup_form(const std::string& name);
inline const char* to_string(LookupForm f) { return kLookupFormNames[static_cast<int>(f)]; }

struct TrainConfig {
  std::vector<std::filesystem::path> data;         // training datasets (HDF5)
  std::optional<std::filesystem::path> validation;  // separate validation dataset; else `split` of the data
  // Datasets that train in every cell and are never scored: scans of OTHER places than `data`
  // (more scenery without touching the split). Appended after `data`: in train_frames/train_on
  // the last train_also.size() sets are these.
  std::vector<std::filesystem::path> train_also;
  // Split of the training sets when there is no separate validation set (data/split.h): "guarded"
  // (guard bands of twice this model's receptive-field half-width), "guarded:<half-width>" (at
  // least the model's), "interleaved" (leaks across neighbouring columns; for comparison), "frames:<id>,...".
  std::string split = "guarded";
  pgm::EncoderConfig encoder;
  int base = 16, depth = 4;
  // A learned gain and offset per PGM row (= laser) on the output (nn/unet.h, row_affine), one
  // per row of the training grid; the row is known at inference, so nothing else is needed.
  bool row_affine = false;
  // Learn the residual over a lookup base (nn/unet.h, lookup; train/lookup_fit.h): a class x range
  // table + per-beam offsets fitted on the training cells, fed as an input channel and added to the
  // output. The model starts at the lookup's prediction; it travels in the checkpoint.
  bool lookup_base = false;
  // The lookup base's form: "groups" (the encoder's class groups, plain per-row mean offsets) or
  // "classes" (the intensity loop's best lookup: one group per class id, per-beam offsets fitted as
  // the loop fits them; train/lookup_fit.h). "classes" replaces the encoder's class groups with
  // one_group_per_class(), so the network's class input is one-hot over every class too. Kept as
  // its spelling (callers outside train/ set it so); train_frames parses it once (parse_lookup_form).
  std::string lookup_form = "groups";
  // Early stopping that cannot leak (data/split.h inner_split, train/early_stop.h): the network
  // does not train on an inner region of `inner_columns` columns and its guard band; the epoch
  // with the lowest MAE there is chosen and its weights kept; the scored validation regions are
  // measured once, for that epoch's weights. Needs a guarded region split of --data. The lookup
  // base, if any, is still fitted on all the split's training columns (inner region included),
  // so that the untrained model is the same table as without early stopping.
  bool early_stop = false;
  int inner_columns = 32;
  // With a frame hold-out (split "frames:..."): the inner set is these training frames, held out
  // whole (other places; data/split.h inner_frames_split).
  std::vector<std::string> inner_frames;
  int patience = 0;  // stop after this many epochs without a new inner best (0: run every epoch)
  // With lookup_base and early_stop: after the epoch is chosen, scale the network's residual over
  // the table by the factor in {0, 0.05, ..., 1} with the lowest inner MAE (train/residual_shrink.h).
  // 0 gives the table back, 1 the chosen epoch unchanged; the scored regions never take part.
  bool shrink_residual = false;
  // Output heads (nn/heads.h), e.g. "mean,log_scale_laplace": channel 0 is the mean, trained with
  // masked MSE + L2 exactly as with "mean" alone; a spread head (log_scale_gaussian or
  // log_scale_laplace) adds its NLL on the same cells, with no gradient to the mean (so the mean's
  // MAE is not traded for the likelihood). "mean" alone is today's single-output model, bit for bit.
  std::string heads = "mean";
  // Weight of the spread head's NLL. It trains the spread's own output parameters only (the shared
  // layers learn from the mean's MSE alone: training_run.cpp spread_step), so with Adam the weight
  // barely matters; 0 switches the NLL off (tests show the spread is then not learnt).
  float spread_weight = 1.f;
  int epochs = 100;
  int steps_per_epoch = 0;  // 0: one step per batch of frames (ceil(frames / batch))
  int batch = 1;
  int crop_columns = 0;     // train on random azimuth crops this wide (0: whole scans)
  float lr = 2e-3f;
  float final_lr_fraction = 0.05f;  // cosine decay from lr to lr * this over the run
  float lambda = 1e-6f;             // L2 weight on sum(w^2)
  std::uint64_t seed = 1;
  int threads = 2;
  bool augment_roll = true;    // random rotation about z: a spinning sensor sees the scene at any azimuth
  bool augment_mirror = true;  // left-right mirror
  std::filesystem::path out = "checkpoint.h5";  // empty: no checkpoints (train_on only)
  bool resume = false;         // continue from `out` if it exists
  // How the model's 3x3 kernels are chosen (nn/kernel_plan.h): rule (the fixed rules; the default
  // everywhere) or calibrated (measured on this CPU, cached; lidar-train --kernels calibrated).
  // Not in train_config: a resume takes the checkpoint's recorded plan, whatever this says.
  nn::PlanMode kernels = nn::PlanMode::rule;
  // Settings that may differ from the checkpoint's on resume (names as in its train_config,
  // e.g. "epochs", "lr"); any other difference is refused. Every field above that changes the
  // run is recorded in train_config (trainer.cpp, run_settings) and so compared.
  std::vector<std::string> resume_overrides;
  // At the end, also write the weights alone (no optimizer state): a third of the size, for
  // shipping a model for inference.
  std::optional<std::filesystem::path> export_weights;
  bool progress = true;
  // How frames are read (results are the same bit for bit either way, so neither is in
  // train_config): the next step's frames on a background thread; a file whose frames fit in
  // this many MB is kept in memory once read (larger files are read per step).
  bool prefetch = true;
  int cache_mb = 256;
  // Train on datasets whose recorded intensity scales differ (data/intensity_scale.h); refused
  // otherwise. Datasets that record no scale (written before 2026-11-27) are never compared.
  bool mix_intensity_scales = false;
};

// A spread head's validation (train/spread_metrics.h): mean NLL (nats per cell) of the measured
// intensity under the predicted distribution, and the share of cells inside its central 50 % and
// 90 % intervals (a calibrated spread gives 0.5 and 0.9).
struct SpreadMetrics {
  double nll = 0, within50 = 0, within90 = 0;
  long cells = 0;
  // The factor of the predicted scale that maximises the likelihood of these cells (Laplace:
  // mean |y - mean| / b; Gaussian: sqrt(mean (y - mean)^2 / sigma^2)); 1 = already calibrated.
  double mle_factor = 1;
  // With a zero head (nn/heads.h zero_logit): the mean predicted P(intensity = 0) and the measured
  // share of zeros on the same cells; -1 without one.
  double zero_predicted = -1, zero_measured = -1;
};

struct EpochReport {
  int epoch = 0;       // 1-based
  std::int64_t step = 0;
  double train_loss = 0;  // mean total loss over the epoch's steps
  data::Metrics validation;  // with early_stop: not measured (cells 0)
  std::optional<data::Metrics> inner;  // with early_stop: MAE/RMSE on the inner region
  std::optional<SpreadMetrics> spread;  // with a spread head: on the scored validation cells
  // Wall time of the epoch's steps (since the epoch or the run started) and of its validation.
  double train_seconds = 0, validation_seconds = 0;
  int samples = 0;  // frames (crops) the epoch's steps trained on
};

struct TrainResult {
  std::vector<EpochReport> epochs;
  std::optional<data::Metrics> lookup_validation;  // with lookup_base: the table alone, before training
  bool interrupted = false;
  std::int64_t steps = 0;
  // With early_stop: the chosen epoch (1-based), the scored validation of its weights (measured
  // once, after the choice), and the inner region, its guard band and the training columns left.
  int chosen_epoch = 0;
  std::optional<data::Metrics> chosen_validation;
  std::optional<SpreadMetrics> chosen_spread;  // with early_stop and a spread head (calibrated)
  // With early_stop and a spread head: the spread's calibration factor fitted on the inner region
  // (train/spread_calibration.h), the inner cells it was fitted on, and, for the report only, the
  // scored validation of the spread before the factor.
  std::optional<double> spread_scale;
  std::optional<SpreadMetrics> spread_calibration_cells, uncalibrated_spread;
  // With shrink_residual: the factor chosen and the inner MAE at each factor tried; and, for the
  // report only (after the choice), the scored validation of the chosen epoch left unscaled.
  std::optional<double> residual_scale;
  std::optional<data::Metrics> unscaled_validation;
  std::vector<std::pair<double, double>> residual_scale_inner_mae;
  std::string inner_region;
  std::shared_ptr<nn::UNet> model;  // the weights at the end (with early_stop: the chosen epoch's)
  nn::Checkpoint meta;              // what a checkpoint of them records (/config, /state)
};

// Set from a SIGINT handler; the loop saves a checkpoint and returns at the next step boundary.
std::atomic<bool>& stop_requested();

// Runs training as configured; `on_epoch` is called after each epoch's validation.
TrainResult train(const TrainConfig& config, const std::function<void(const EpochReport&)>& on_epoch = {});

// The same on frame sources (data/frame_source.h: files read lazily, or sets in memory); the
// sources name themselves in errors. train() and train_on() come here.
TrainResult train_frames(const TrainConfig& config, const std::vector<const data::FrameSource*>& sets,
                         const data::FrameSource* validation = nullptr,
                         const std::function<void(const EpochReport&)>& on_epoch = {});

// The same on datasets already in memory (config.data and config.validation are not read):
// `names` name the sets in errors; without `validation`, the sector split of the training sets
// validates. For callers that build datasets themselves, e.g. the intensity loop (qualify/).
TrainResult train_on(const TrainConfig& config, const std::vector<const data::Dataset*>& sets,
                     const std::vector<std::string>& names, const data::Dataset* validation = nullptr,
                     const std::function<void(const EpochReport&)>& on_epoch = {});

// Predicts the target channel for every frame of a dataset with a trained model: [N, 1, H, W].
nn::Tensor predict_dataset(nn::UNet& model, const pgm::EncoderConfig& encoder, const data::Dataset& dataset);

// Encoder and architecture stored in a checkpoint's /config attributes.
pgm::EncoderConfig encoder_from_checkpoint(const std::filesystem::path& checkpoint);

}  // namespace lidarsim::train
