#pragma once
// Derived forms of convolution weights (packed for the direct or the bf16 kernel) kept across
// UNet::predict calls: the weights do not change between them, and packing them every call cost
// 4-7 % of a bf16 inference at batch 1. The Winograd-transformed weights stay per call: cached
// they took as much CPU time as they saved (one shared buffer stays in cache, a transformed copy
// of every layer, 4x the weights, does not). An entry is served only while the weights
// are byte-identical to the copy taken when it was filled (one memcmp per use), so a weight
// changed by anyone (optimizer, checkpoint load, a test writing the arena) is never served stale.
// Training (forward/backward) does not use it: its weights change every step.
#include <cstddef>

namespace lidarsim::nn::detail {

// Which derived form; together with the weight pointer, count and the two shape numbers the key.
enum class WeightForm { direct, bf16 };

// A 64-byte aligned buffer of `bytes` for form `form` of weight[0, count) (a, b: the shape
// numbers the form depends on, e.g. co and ci). *valid says whether it already holds that form
// of exactly these weight values; if not, the caller must fill it before the next lookup (the
// copy of the weights is taken now). Not thread-safe (the conv ops run one at a time).
void* cached_weight_form(WeightForm form, const float* weight, std::size_t count, int a, int b, std::size_t bytes,
                         bool* valid);

// Whether the conv ops consult the cache now: while UNet::predict runs (Bf16ConvScope).
bool weight_cache_active();

// Drops every entry (frees their memory).
void clear_weight_cache();

namespace testhook {
// Lookups that found valid entries since the process started.
std::size_t weight_cache_hits();
}  // namespace testhook

}  // namespace lidarsim::nn::detail
