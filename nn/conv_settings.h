#pragma once
// What a model hands to its convolution ops on every call, as an argument: which 3x3 algorithm,
// whether the forward pass takes the bf16 kernel, and the model's own cache of packed weights.
// None of it is process-wide, so models running in several threads at once (the FMU: one
// instance per lidar) each run with their own. Ops called outside a model (tests, benches) get a
// default-constructed one: the process default algorithm, fp32, no cache, no plan (the rules).
namespace lidarsim::nn {
class KernelPlan;  // nn/kernel_plan.h
}
namespace lidarsim::nn::detail {

// Which algorithm the forward pass, the input gradient and the weight gradient take. automatic:
// Winograd F(4x4, 3x3) (nn/winograd.h) where the rule measured in the network says it is
// faster, direct elsewhere.
enum class Conv3x3Path { automatic, direct, winograd };

// The process default, for models and ops that are not given their own: LIDARSIM_CONV3X3
// (direct, winograd or auto), read once at start-up; tests and benches set it directly (before
// any thread runs a model: it is a plain value, not synchronised).
void set_conv3x3_path(Conv3x3Path path);
Conv3x3Path conv3x3_path();

class WeightCache;  // nn/weight_cache.h

struct ConvSettings {
  Conv3x3Path conv3x3 = conv3x3_path();
  bool bf16 = false;                   // 3x3 forward passes in bf16 where that kernel is faster (inference)
  WeightCache* weight_cache = nullptr;  // packed weights kept across calls (inference; null: pack per call)
  // The model's kernel choices per conv shape and pass (nn/kernel_plan.h), consulted when conv3x3
  // is automatic; null: the fixed rules.
  KernelPlan* plan = nullptr;
};

}  // namespace lidarsim::nn::detail
