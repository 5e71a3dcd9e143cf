#pragma once
// Optimizers over a ParamArena: one loop over one buffer. State is exposed for checkpoints.
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "nn/params.h"

namespace lidarsim::nn {

enum class OptimizerKind { Adam, Sgd /* with momentum */ };
inline constexpr int kOptimizerKinds = 2;
// The names checkpoints store (config "optimizer.kind" and /optimizer "kind"), by OptimizerKind.
inline constexpr const char* kOptimizerKindNames[kOptimizerKinds] = {"adam", "sgd"};
static_assert(static_cast<int>(OptimizerKind::Sgd) + 1 == kOptimizerKinds, "kOptimizerKindNames: one per OptimizerKind");
std::string to_string(OptimizerKind kind);
// The kind of a stored name; nullopt for any other string (the caller names its file and field).
std::optional<OptimizerKind> optimizer_kind_from_string(const std::string& name);

struct OptimizerConfig {
  OptimizerKind kind = OptimizerKind::Adam;
  float lr = 1e-3f;
  float beta1 = 0.9f, beta2 = 0.999f, eps = 1e-8f;  // Adam, PyTorch's defaults
  float momentum = 0.9f;                              // SGD
  float clip_norm = 0.f;                              // global gradient-norm clip; 0 = off
};

class Optimizer {
 public:
  Optimizer(const OptimizerConfig& config, std::size_t num_params);
  // One update from arena.grads() (PyTorch semantics, bias-corrected Adam); step() counts from 1.
  void step(ParamArena& params);
  const OptimizerConfig& config() const { return config_; }
  void set_lr(float lr) { config_.lr = lr; }

  // Checkpointed state: Adam m and v (or SGD velocity in m), and the step count.
  std::vector<float>& m() { return m_; }
  std::vector<float>& v() { return v_; }
  const std::vector<float>& m() const { return m_; }
  const std::vector<float>& v() const { return v_; }
  std::int64_t steps() const { return steps_; }
  void set_steps(std::int64_t s) { steps_ = s; }

 private:
  OptimizerConfig config_;
  std::vector<float> m_, v_;
  std::int64_t steps_ = 0;
  std::vector<float> scale_;  // per-element lr factor (ParamInfo::lr_scale), filled on the first step
};

}  // namespace lidarsim::nn
