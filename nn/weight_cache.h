#pragma once
// Derived forms of convolution weights (packed for the direct, the bf16 or the AMX kernel) kept across
// UNet::predict calls: the weights do not change between them, and packing them every call cost
// 4-7 % of a bf16 inference at batch 1. The Winograd-transformed weights stay per call: cached
// they took as much CPU time as they saved (one shared buffer stays in cache, a transformed copy
// of every layer, 4x the weights, does not). An entry is served only while the weights
// are byte-identical to the copy taken when it was filled (one memcmp per use), so a weight
// changed by anyone (optimizer, checkpoint load, a test writing the arena) is never served stale.
// Each UNet owns one and hands it to its ops in predict() (nn/conv_settings.h); training
// (forward/backward) does not use it: its weights change every step.
#include <cstddef>
#include <memory>
#include <vector>

namespace lidarsim::nn::detail {

// Which derived form; together with the weight pointer, count and the two shape numbers the key.
enum class WeightForm { direct, bf16, amx };

class WeightCache {
 public:
  WeightCache();
  ~WeightCache();
  WeightCache(const WeightCache&) = delete;
  WeightCache& operator=(const WeightCache&) = delete;

  // A 64-byte aligned buffer of `bytes` for form `form` of weight[0, count) (a, b: the shape
  // numbers the form depends on, e.g. co and ci). *valid says whether it already holds that form
  // of exactly these weight values; if not, the caller must fill it before the next lookup (the
  // copy of the weights is taken now). Not thread-safe: one model runs one call at a time.
  void* get(WeightForm form, const float* weight, std::size_t count, int a, int b, std::size_t bytes, bool* valid);

  // Drops every entry (frees their memory).
  void clear();

  // Lookups that found a valid entry.
  std::size_t hits() const { return hits_; }

 private:
  struct Entry;
  std::vector<Entry> entries_;
  std::size_t bytes_ = 0, hits_ = 0;
};

namespace testhook {
// Lookups that found a valid entry, over every cache of the process (a statistic, atomic).
std::size_t weight_cache_hits();
}  // namespace testhook

}  // namespace lidarsim::nn::detail
