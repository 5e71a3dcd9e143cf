#include "nn/params.h"

#include <algorithm>
#include <cmath>

#include "common/error.h"
#include "nn/parallel.h"

namespace lidarsim::nn {

int ParamArena::add(const std::string& name, Shape shape, bool decays, float decay_center, float lr_scale) {
  if (finalized_) throw Error("ParamArena: " + name + ": cannot add a parameter after finalize()");
  if (find(name) >= 0) throw Error("ParamArena: " + name + ": parameter registered twice");
  if (shape.numel() == 0) throw Error("ParamArena: " + name + ": empty shape " + shape.str());
  // Contiguous, no padding: offsets are the running sum of sizes, so the arena is exactly the
  // concatenation of all parameters in registration order.
  if (!(lr_scale >= 0) || !std::isfinite(lr_scale)) throw Error("ParamArena: " + name + ": lr_scale must be >= 0 (0: frozen)");
  infos_.push_back(ParamInfo{name, shape, decays, total_, decay_center, lr_scale});
  total_ += shape.numel();
  return static_cast<int>(infos_.size()) - 1;
}

void ParamArena::finalize() {
  values_.resize(Shape{1, 1, 1, static_cast<int>(total_)});
  grads_.resize(Shape{1, 1, 1, static_cast<int>(total_)});
  finalized_ = true;
}

int ParamArena::find(const std::string& name) const {
  for (std::size_t i = 0; i < infos_.size(); ++i)
    if (infos_[i].name == name) return static_cast<int>(i);
  return -1;
}

// In parallel: unet-ref's 7.8 MB took the other thread's time at every step.
void ParamArena::zero_grads() {
  float* g = grads_.data();
  detail::parallel_ranges(static_cast<long>(grads_.numel()), grads_.numel() > (1u << 15),
                          [g](long b, long e) { std::fill(g + b, g + e, 0.f); });
}

}  // namespace lidarsim::nn
