#include "nn/weight_cache.h"

#include <atomic>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <new>
#include <vector>

namespace lidarsim::nn::detail {

namespace {

struct FreeDeleter {
  void operator()(void* p) const { std::free(p); }
};

// Past either bound everything is dropped (one UNet has a few dozen entries of a few MB each; a
// model whose tensors move, e.g. a reloaded checkpoint, leaves stale keys behind).
constexpr std::size_t kMaxEntries = 256;
constexpr std::size_t kMaxBytes = std::size_t{1} << 30;

std::atomic<std::size_t> g_hits_all{0};

}  // namespace

struct WeightCache::Entry {
  WeightForm form;
  const float* weight;  // compared as a key only, never read through (it may be stale)
  std::size_t count;
  int a, b;
  std::vector<float> copy;  // the weights the derived form was made from
  std::unique_ptr<void, FreeDeleter> derived;
  std::size_t bytes = 0;
};

WeightCache::WeightCache() = default;
WeightCache::~WeightCache() = default;

void* WeightCache::get(WeightForm form, const float* weight, std::size_t count, int a, int b, std::size_t bytes,
                       bool* valid) {
  Entry* e = nullptr;
  for (Entry& x : entries_)
    if (x.form == form && x.weight == weight && x.count == count && x.a == a && x.b == b) e = &x;
  if (e && e->bytes == bytes && std::memcmp(e->copy.data(), weight, count * sizeof(float)) == 0) {
    ++hits_;
    g_hits_all.fetch_add(1, std::memory_order_relaxed);
    *valid = true;
    return e->derived.get();
  }
  *valid = false;
  if (!e) {
    const std::size_t need = bytes + count * sizeof(float);
    if (entries_.size() >= kMaxEntries || bytes_ + need > kMaxBytes) clear();
    entries_.push_back(Entry{form, weight, count, a, b, {}, nullptr, 0});
    e = &entries_.back();
  }
  if (e->bytes != bytes) {
    bytes_ -= e->bytes;
    e->derived.reset();
    e->bytes = 0;
    void* p = std::aligned_alloc(64, (bytes + 63) / 64 * 64);
    if (!p) throw std::bad_alloc();
    e->derived.reset(p);
    e->bytes = bytes;
    bytes_ += bytes;
  }
  if (e->copy.size() != count) {
    bytes_ += (count - e->copy.size()) * sizeof(float);
    e->copy.resize(count);
  }
  std::memcpy(e->copy.data(), weight, count * sizeof(float));
  return e->derived.get();
}

void WeightCache::clear() {
  entries_.clear();
  bytes_ = 0;
}

namespace testhook {
std::size_t weight_cache_hits() { return g_hits_all.load(std::memory_order_relaxed); }
}  // namespace testhook

}  // namespace lidarsim::nn::detail
