#include "nn/weight_cache.h"

#include <cstdlib>
#include <cstring>
#include <memory>
#include <new>
#include <vector>

#include "nn/precision.h"

namespace lidarsim::nn::detail {

namespace {

struct FreeDeleter {
  void operator()(void* p) const { std::free(p); }
};

struct Entry {
  WeightForm form;
  const float* weight;  // compared as a key only, never read through (it may be stale)
  std::size_t count;
  int a, b;
  std::vector<float> copy;  // the weights the derived form was made from
  std::unique_ptr<void, FreeDeleter> derived;
  std::size_t bytes = 0;
};

// Past either bound everything is dropped (models come and go in tests and tools; one UNet
// has a few dozen entries of a few MB each).
constexpr std::size_t kMaxEntries = 256;
constexpr std::size_t kMaxBytes = std::size_t{1} << 30;

std::vector<Entry> g_entries;
std::size_t g_bytes = 0, g_hits = 0;

}  // namespace

void* cached_weight_form(WeightForm form, const float* weight, std::size_t count, int a, int b, std::size_t bytes,
                         bool* valid) {
  Entry* e = nullptr;
  for (Entry& x : g_entries)
    if (x.form == form && x.weight == weight && x.count == count && x.a == a && x.b == b) e = &x;
  if (e && e->bytes == bytes && std::memcmp(e->copy.data(), weight, count * sizeof(float)) == 0) {
    ++g_hits;
    *valid = true;
    return e->derived.get();
  }
  *valid = false;
  if (!e) {
    const std::size_t need = bytes + count * sizeof(float);
    if (g_entries.size() >= kMaxEntries || g_bytes + need > kMaxBytes) clear_weight_cache();
    g_entries.push_back(Entry{form, weight, count, a, b, {}, nullptr, 0});
    e = &g_entries.back();
  }
  if (e->bytes != bytes) {
    g_bytes -= e->bytes;
    e->derived.reset();
    e->bytes = 0;
    void* p = std::aligned_alloc(64, (bytes + 63) / 64 * 64);
    if (!p) throw std::bad_alloc();
    e->derived.reset(p);
    e->bytes = bytes;
    g_bytes += bytes;
  }
  if (e->copy.size() != count) {
    g_bytes += (count - e->copy.size()) * sizeof(float);
    e->copy.resize(count);
  }
  std::memcpy(e->copy.data(), weight, count * sizeof(float));
  return e->derived.get();
}

bool weight_cache_active() { return predict_active(); }

void clear_weight_cache() {
  g_entries.clear();
  g_bytes = 0;
}

namespace testhook {
std::size_t weight_cache_hits() { return g_hits; }
}  // namespace testhook

}  // namespace lidarsim::nn::detail
