// lidar-train: train the intensity UNet on Polar Grid Map datasets made by `lidar-data import`.
#include <malloc.h>

#include <algorithm>
#include <csignal>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <optional>
#include <sstream>

#include <cxxopts.hpp>

#include "common/atomic_file.h"
#include "common/error.h"
#include "common/file_lock.h"
#include "nn/receptive_field.h"
#include "train/distributed.h"
#include "train/trainer.h"

namespace {

void on_sigint(int) {
  lidarsim::train::stop_requested().store(true);
  std::signal(SIGINT, SIG_DFL);  // a second Ctrl-C ends the process at once
}

std::vector<std::string> split_list(const std::string& text) {
  std::vector<std::string> out;
  std::stringstream ss(text);
  for (std::string item; std::getline(ss, item, ',');)
    if (!item.empty()) out.push_back(item);
  return out;
}

// The command line: every option with its help and default.
cxxopts::Options command_line() {
  cxxopts::Options options("lidar-train",
                           "Train the intensity UNet (masked MSE + L2 on the weights) on Polar Grid Map datasets.\n"
                           "Without --val, validation holds out the cells of --split (data/split.h): by default\n"
                           "azimuth regions with guard bands of twice the model's receptive-field half-width.\n"
                           "Ctrl-C saves a checkpoint and exits; --resume continues it to the same result.\n"
                           "mpirun -np N lidar-train ... trains on N processes (--batch: the global batch, a\n"
                           "multiple of N; --threads: per process); rank 0 writes the checkpoint and the log.");
  // clang-format off
  options.add_options()
    ("data", "training dataset(s), HDF5 from lidar-data import (comma-separated)", cxxopts::value<std::string>())
    ("train-also", "more training datasets (comma-separated), trained on in every cell and never scored: scans of OTHER places than --data", cxxopts::value<std::string>())
    ("val", "separate validation dataset (default: --split of --data)", cxxopts::value<std::string>())
    ("mix-intensity-scales", "train and validate on datasets whose recorded intensity scales differ (e.g. KITTI reflectance "
     "with nuScenes intensity / 255); refused without it")
    ("split", "guarded | guarded:<half-width> | interleaved (leaks; for comparison) | frames:<id>,...", cxxopts::value<std::string>()->default_value("guarded"))
    ("channels", "input channels of the PGM, comma-separated", cxxopts::value<std::string>()->default_value("range,class,material"))
    ("epochs", "epochs", cxxopts::value<int>()->default_value("100"))
    ("steps-per-epoch", "steps per epoch (0: one pass over the frames)", cxxopts::value<int>()->default_value("0"))
    ("batch", "frames per step (under mpirun: over all ranks)", cxxopts::value<int>()->default_value("1"))
    ("crop", "train on random azimuth crops this many columns wide (0: whole scans)", cxxopts::value<int>()->default_value("0"))
    ("lr", "Adam learning rate (cosine decay to 5% over the run)", cxxopts::value<float>()->default_value("0.002"))
    ("lambda", "L2 weight on the sum of squared weights", cxxopts::value<float>()->default_value("1e-6"))
    ("base", "UNet base width", cxxopts::value<int>()->default_value("16"))
    ("depth", "UNet depth (number of poolings)", cxxopts::value<int>()->default_value("4"))
    ("row-affine", "learn a gain and an offset per PGM row (per laser) on the output, pulled toward 1 and 0 by the L2 term")
    ("lookup-base", "learn the residual over a class x range + per-beam lookup table fitted on the training cells (input channel + added to the output); "
     "=groups (default): the class groups of the input encoding; =classes: every class, per-beam offsets as the intensity loop fits them (its best lookup)",
     cxxopts::value<std::string>()->implicit_value("groups"))
    ("heads", "output heads: mean (default: the paper's single output), or mean,log_scale_laplace / mean,log_scale_gaussian: "
     "a per-cell intensity spread trained with the NLL around the mean (the mean keeps masked MSE + L2); "
     "then ,zero_logit: P(intensity = 0) trained with BCE (sampling draws 0 with it)",
     cxxopts::value<std::string>()->default_value("mean"))
    ("early-stop", "choose the epoch on an inner region carved out of the training columns (with its own guard band; never the scored regions), "
     "keep that epoch's weights, score the validation regions once")
    ("inner-columns", "with --early-stop: width of the inner region in columns", cxxopts::value<int>()->default_value("32"))
    ("inner-frames", "with --early-stop and --split frames:...: the inner set, training frames held out whole (comma-separated ids)",
     cxxopts::value<std::string>())
    ("patience", "with --early-stop: stop after this many epochs without a new inner best (0: run every epoch)",
     cxxopts::value<int>()->default_value("0"))
    ("shrink-residual", "with --lookup-base and --early-stop: scale the network's residual over the table by the factor "
     "in 0, 0.05, ..., 1 with the lowest inner MAE (0: the table, 1: the network as trained)")
    ("seed", "random seed", cxxopts::value<std::uint64_t>()->default_value("1"))
    ("threads", "OpenMP threads", cxxopts::value<int>()->default_value("2"))
    ("kernels", "how each 3x3 conv's kernel is chosen: rule (the fixed rules in code; the default) or "
     "calibrated (time the candidates this CPU has the first time a layer shape runs here, cached in "
     "$LIDARSIM_KERNEL_CACHE or ~/.cache/lidarsim); the choices go into the checkpoint and --resume takes them again",
     cxxopts::value<std::string>()->default_value("rule"))
    ("no-augment", "no azimuth roll or mirror")
    ("out", "checkpoint (HDF5), written every epoch", cxxopts::value<std::string>()->default_value("checkpoint.h5"))
    ("resume", "continue from --out if it exists (refused when a setting differs from the checkpoint's)")
    ("override", "with --resume: settings that may differ from the checkpoint's, comma-separated (e.g. epochs,lr)",
     cxxopts::value<std::string>())
    ("export-weights", "at the end, also write the weights alone (for inference) here", cxxopts::value<std::string>())
    ("log", "write per-epoch metrics as CSV here", cxxopts::value<std::string>())
    ("cache-mb", "keep a file's frames in memory once read if all of them fit in this many MB (else read per step)",
     cxxopts::value<int>()->default_value("256"))
    ("no-prefetch", "read a step's frames when it starts, not on a background thread during the step before")
    ("quiet", "no progress bar")
    ("h,help", "show this help");
  // clang-format on
  return options;
}

// The run as the command line asks for it (TrainConfig checks the values themselves).
lidarsim::train::TrainConfig config_from(const cxxopts::ParseResult& args) {
  lidarsim::train::TrainConfig config;
  for (const auto& p : split_list(args["data"].as<std::string>())) config.data.emplace_back(p);
  if (args.count("train-also"))
    for (const auto& p : split_list(args["train-also"].as<std::string>())) config.train_also.emplace_back(p);
  if (args.count("val")) config.validation = args["val"].as<std::string>();
  config.encoder.channels = split_list(args["channels"].as<std::string>());
  config.epochs = args["epochs"].as<int>();
  config.steps_per_epoch = args["steps-per-epoch"].as<int>();
  config.batch = args["batch"].as<int>();
  config.crop_columns = args["crop"].as<int>();
  config.lr = args["lr"].as<float>();
  config.lambda = args["lambda"].as<float>();
  config.base = args["base"].as<int>();
  config.depth = args["depth"].as<int>();
  config.row_affine = args.count("row-affine") > 0;
  config.lookup_base = args.count("lookup-base") > 0;
  if (config.lookup_base) config.lookup_form = args["lookup-base"].as<std::string>();
  config.heads = args["heads"].as<std::string>();
  config.early_stop = args.count("early-stop") > 0;
  config.inner_columns = args["inner-columns"].as<int>();
  config.patience = args["patience"].as<int>();
  if (args.count("inner-frames")) config.inner_frames = split_list(args["inner-frames"].as<std::string>());
  config.shrink_residual = args.count("shrink-residual") > 0;
  if (!config.early_stop && (args.count("inner-columns") || args.count("patience") || args.count("inner-frames")))
    throw lidarsim::Error("lidar-train: --inner-columns, --inner-frames and --patience need --early-stop");
  config.seed = args["seed"].as<std::uint64_t>();
  config.threads = args["threads"].as<int>();
  config.kernels = lidarsim::nn::parse_plan_mode(args["kernels"].as<std::string>(), "lidar-train: --kernels");
  config.augment_roll = config.augment_mirror = !args.count("no-augment");
  config.out = args["out"].as<std::string>();
  config.resume = args.count("resume") > 0;
  if (args.count("override")) config.resume_overrides = split_list(args["override"].as<std::string>());
  if (args.count("export-weights")) config.export_weights = args["export-weights"].as<std::string>();
  config.progress = !args.count("quiet");
  config.cache_mb = args["cache-mb"].as<int>();
  config.prefetch = !args.count("no-prefetch");
  config.split = args["split"].as<std::string>();
  config.mix_intensity_scales = args.count("mix-intensity-scales") > 0;
  return config;
}

// One trainer per output: a second one is refused instead of silently overwriting it. Under
// MPI rank 0 alone writes, so it alone holds the lock.
void lock_outputs(std::optional<lidarsim::OutputLock>& lock, const lidarsim::train::TrainConfig& config,
                  const std::string& log) {
  lidarsim::train::Distributed& dist = lidarsim::train::Distributed::world();
  std::string lock_error;
  try {
    if (dist.root()) {
      lock.emplace(config.out);
      for (const auto& path : {config.out, config.export_weights.value_or(""), std::filesystem::path(log)})
        if (!path.empty()) lidarsim::remove_stale_temp_files(path);  // left by a run that was killed while writing
    }
  } catch (const std::exception& e) {
    if (!dist.active()) throw;
    lock_error = e.what();
  }
  dist.agree(lock_error);
}

// Rank 0's summary of a finished run on stdout: the residual scale, the chosen epoch, the final figures.
void print_summary(const lidarsim::train::TrainResult& result, const lidarsim::train::TrainConfig& config,
                   int half_width) {
  if (result.model) {  // the kernels the run took, held fixed for it (also in the checkpoint's /config/kernel_plan)
    const lidarsim::nn::KernelPlan& plan = result.model->kernel_plan();
    std::printf("kernels: %s, %zu choices (the checkpoint's /config/kernel_plan; listed on stderr)\n",
                lidarsim::nn::to_string(plan.mode()), plan.entries().size());
    std::fprintf(stderr, "lidar-train: kernel plan (%s):\n%s", lidarsim::nn::to_string(plan.mode()), plan.describe().c_str());
  }
  if (result.residual_scale) {
    std::string tried;
    for (const auto& [factor, mae] : result.residual_scale_inner_mae) {
      char item[40];
      std::snprintf(item, sizeof item, "%s%.2f: %.4f", tried.empty() ? "" : ", ", factor, mae);
      tried += item;
    }
    std::printf("residual scale: %.2f (inner MAE by factor: %s); validation of the chosen epoch unscaled: MAE %.4f RMSE %.4f\n",
                *result.residual_scale, tried.c_str(), result.unscaled_validation->mae, result.unscaled_validation->rmse);
  }
  if (result.chosen_validation) {
    const auto& chosen = result.epochs[static_cast<std::size_t>(result.chosen_epoch - 1)];
    std::printf("early stopping: %s; chosen epoch %d of %zu run (inner MAE %.4f); its weights kept\n"
                "final: val MAE %.4f RMSE %.4f over %ld cells (chosen epoch %d, scored once); checkpoint %s; "
                "receptive field half-width %d columns; split %s\n",
                result.inner_region.c_str(), result.chosen_epoch, result.epochs.size(), chosen.inner->mae,
                result.chosen_validation->mae, result.chosen_validation->rmse, result.chosen_validation->cells,
                result.chosen_epoch, config.out.c_str(), half_width, config.validation ? "--val" : config.split.c_str());
  } else if (!result.epochs.empty()) {
    const auto& last = result.epochs.back();
    std::printf("final: val MAE %.4f RMSE %.4f over %ld cells; checkpoint %s; receptive field half-width %d columns; "
                "split %s\n",
                last.validation.mae, last.validation.rmse, last.validation.cells, config.out.c_str(), half_width,
                config.validation ? "--val" : config.split.c_str());
  }
  std::optional<lidarsim::train::SpreadMetrics> final_spread = result.chosen_spread;
  if (!final_spread && !result.epochs.empty()) final_spread = result.epochs.back().spread;
  if (result.spread_scale) {
    const auto& inner = *result.spread_calibration_cells;
    const auto& raw = *result.uncalibrated_spread;
    std::printf("spread calibration: scale x%.4f, fitted on the inner region (%ld cells: before, NLL %.4f, inside 50%% %.3f, "
                "90%% %.3f); validation before it: NLL %.4f, inside 50%% %.3f, 90%% %.3f\n",
                *result.spread_scale, inner.cells, inner.nll, inner.within50, inner.within90, raw.nll, raw.within50,
                raw.within90);
    const lidarsim::nn::SpreadResidual& r = result.model->config().spread_residual;
    std::printf("spread residual: %d quantiles of (y - mean) / scale in each of %d bins of the mean, fitted on the same "
                "cells; draws rounded to the targets' grid step %g (0: continuous)\n",
                r.levels, r.bins(), r.target_step);
  } else if (final_spread) {
    std::printf("spread not calibrated (scale x1): --early-stop fits its factor on the inner region\n");
  }
  if (final_spread)
    std::printf("final spread (%s): NLL %.4f nats/cell; inside the 50%% interval %.3f, the 90%% interval %.3f (%ld cells)\n",
                config.heads.c_str(), final_spread->nll, final_spread->within50, final_spread->within90, final_spread->cells);
  if (final_spread && final_spread->zero_predicted >= 0)
    std::printf("final zero head: predicted P(intensity = 0) %.4f on average, measured share of zeros %.4f (same cells)\n",
                final_spread->zero_predicted, final_spread->zero_measured);
}

}  // namespace

int main(int argc, char** argv) {
  using namespace lidarsim;
  // Every frame read allocates HDF5's decompression buffers (a few MB) on the prefetching thread;
  // with glibc's defaults its arena hands them back to the system and faults them in again on
  // every read (sys time was a third of a step). Keep freed memory up to 128 MB for reuse.
  mallopt(M_MMAP_THRESHOLD, 32 << 20);
  mallopt(M_TRIM_THRESHOLD, 128 << 20);
  // Under mpirun -np N: N ranks train one model, --batch is split between them (README).
  const train::Distributed::Session mpi(&argc, &argv);
  train::Distributed& dist = train::Distributed::world();
  cxxopts::Options options = command_line();
  try {
    const auto args = options.parse(argc, argv);
    if (args.count("help") || !args.count("data")) {
      if (dist.root()) std::cout << options.help() << "\n";
      return args.count("help") ? 0 : 2;
    }
    const train::TrainConfig config = config_from(args);
    const int half_width = nn::receptive_field_half_width({1, 1, config.base, config.depth});

    std::optional<OutputLock> lock;
    lock_outputs(lock, config, args.count("log") ? args["log"].as<std::string>() : "");

    // With --early-stop the epochs are measured on the inner region only (the scored regions once, at the end).
    std::string csv = config.early_stop ? "epoch,step,train_loss,inner_mae,inner_rmse,inner_cells"
                                        : "epoch,step,train_loss,val_mae,val_rmse,val_cells";
    // A spread head adds its NLL and interval coverage (same cells as the MAE).
    const bool spread = config.heads != "mean";
    csv += spread ? ",spread_nll,within50,within90\n" : "\n";
    std::signal(SIGINT, on_sigint);
    if (dist.active()) std::signal(SIGUSR1, on_sigint);  // mpirun forwards SIGUSR1, not SIGINT, to the ranks
    const auto result = train::train(config, [&](const train::EpochReport& r) {
      const lidarsim::data::Metrics& m = r.inner ? *r.inner : r.validation;
      std::fprintf(stderr, "epoch %d/%d  loss %.5f  %s MAE %.4f  RMSE %.4f  (%ld cells)  -> %s  [%.1f frames/s, validation %.1f s]\n",
                   r.epoch, config.epochs, r.train_loss, r.inner ? "inner" : "val", m.mae, m.rmse, m.cells,
                   config.out.c_str(), r.samples / std::max(1e-9, r.train_seconds), r.validation_seconds);
      if (r.spread)
        std::fprintf(stderr, "    spread: NLL %.4f nats/cell, inside 50%% interval %.3f, inside 90%% interval %.3f\n",
                     r.spread->nll, r.spread->within50, r.spread->within90);
      char line[200];
      std::snprintf(line, sizeof line, "%d,%lld,%.6f,%.6f,%.6f,%ld", r.epoch, static_cast<long long>(r.step),
                    r.train_loss, m.mae, m.rmse, m.cells);
      csv += line;
      if (r.spread) {
        std::snprintf(line, sizeof line, ",%.6f,%.6f,%.6f", r.spread->nll, r.spread->within50, r.spread->within90);
        csv += line;
      }
      csv += "\n";
      if (args.count("log")) write_file_atomically(args["log"].as<std::string>(), csv);
    });
    if (!dist.root()) return result.interrupted ? 130 : 0;  // rank 0 reports
    if (result.interrupted) {
      std::fprintf(stderr, "interrupted at step %lld: checkpoint saved to %s (continue with --resume)\n",
                   static_cast<long long>(result.steps), config.out.c_str());
      return 130;
    }
    print_summary(result, config, half_width);
    return 0;
  } catch (const cxxopts::exceptions::exception& e) {
    if (dist.root()) std::fprintf(stderr, "error: %s (see --help)\n", e.what());
    return 2;
  } catch (const train::FailedElsewhere&) {
    return 1;  // rank 0 prints the error
  } catch (const std::exception& e) {
    // An error the ranks did not agree on: the others may wait for this one, so end them all.
    if (dist.active() && !dynamic_cast<const train::AgreedError*>(&e)) dist.abort(e.what());
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
}
