#include "train/run_settings.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "common/error.h"
#include "nn/heads.h"
#include "train/distributed.h"

namespace lidarsim::train {

LookupForm parse_lookup_form(const std::string& name) {
  for (std::size_t i = 0; i < std::size(kLookupFormNames); ++i)
    if (name == kLookupFormNames[i]) return static_cast<LookupForm>(i);
  throw Error("lidar-train: --lookup-base: must be groups or classes, got \"" + name + "\"");
}

nlohmann::json run_settings(const TrainConfig& c) {
  nlohmann::json j;
  std::vector<std::string> data;
  for (const auto& p : c.data) data.push_back(p.string());
  j["data"] = data;
  j["validation"] = c.validation ? c.validation->string() : "split " + c.split + " of --data";
  if (!c.train_also.empty()) {  // absent when none: a checkpoint without the key compares equal
    std::vector<std::string> also;
    for (const auto& p : c.train_also) also.push_back(p.string());
    j["train_also"] = also;
  }
  j["channels"] = c.encoder.channels;
  j["base"] = c.base;
  j["depth"] = c.depth;
  if (c.row_affine) j["row_affine"] = true;  // absent when off: a checkpoint without the key compares equal
  if (c.lookup_base) j["lookup_base"] = true;
  if (c.lookup_base && parse_lookup_form(c.lookup_form) != LookupForm::groups) j["lookup_form"] = c.lookup_form;
  if (c.early_stop) j["early_stop"] = {{"inner_columns", c.inner_columns}, {"patience", c.patience}};
  if (c.early_stop && !c.inner_frames.empty()) j["early_stop"]["inner_frames"] = c.inner_frames;
  if (c.shrink_residual) j["shrink_residual"] = true;
  if (c.heads != "mean") j["heads"] = c.heads;  // absent for the mean alone: older checkpoints compare equal
  if (c.heads != "mean") j["spread_weight"] = c.spread_weight;
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
  parse_lookup_form(c.lookup_form);  // refuses any other spelling
  if (c.inner_columns < 1 || c.inner_columns > 100000)
    refuse("inner-columns", "must be in [1, 100000]", std::to_string(c.inner_columns));
  if (c.shrink_residual && !(c.lookup_base && c.early_stop))
    refuse("shrink-residual", "needs --lookup-base and --early-stop (the factor is chosen on the inner region)",
           c.lookup_base ? "no --early-stop" : "no --lookup-base");
  const std::vector<nn::HeadKind> heads = nn::parse_heads(c.heads, "lidar-train: --heads");
  if (heads.empty() || heads[0] != nn::HeadKind::mean)
    refuse("heads", "must start with mean (channel 0 is the intensity mean)", "\"" + c.heads + "\"");
  if (heads.size() > 3 ||
      (heads.size() >= 2 && heads[1] != nn::HeadKind::log_scale_gaussian && heads[1] != nn::HeadKind::log_scale_laplace) ||
      (heads.size() == 3 && heads[2] != nn::HeadKind::zero_logit))
    refuse("heads",
           "supported: mean, mean,log_scale_gaussian or mean,log_scale_laplace, each spread optionally followed by "
           "zero_logit (a return head needs a return target)",
           "\"" + c.heads + "\"");
  if (heads.size() > 1 && c.shrink_residual)
    refuse("shrink-residual", "not supported with a spread head (the residual scale would scale the log-scale too)",
           "--heads " + c.heads);
  if (heads.size() > 1 && Distributed::world().active())
    refuse("heads", "a spread head is not supported on several MPI ranks yet (its NLL's denominator is not summed across ranks)",
           "--heads " + c.heads + " on " + std::to_string(Distributed::world().size()) + " ranks");
  if (c.patience < 0 || c.patience > 1000000) refuse("patience", "must be in [0, 1000000] (0: every epoch)", std::to_string(c.patience));
}

}  // namespace lidarsim::train
