#pragma once
// All parameters of a model in one contiguous arena: one buffer for values, one for gradients.
// Optimizers, clipping, checkpoints (and a future all-reduce) are one loop over one buffer.
#include <cstddef>
#include <string>
#include <vector>

#include "nn/tensor.h"

namespace lidarsim::nn {

struct ParamInfo {
  std::string name;    // "<layer>/<field>", e.g. "enc0.conv1/weight"; the HDF5 path under /params
  Shape shape;         // conv: [out, in, kh, kw]; transposed conv: [in, out, 2, 2]; bias: [out, 1, 1, 1]
  bool decays;         // true for weights (in the L2 term), false for biases
  std::size_t offset;  // into values()/grads()
  float decay_center = 0.f;  // the L2 term pulls toward this (1 for a gain, 0 otherwise)
  float lr_scale = 1.f;      // the optimizer's step for this parameter is lr x this; 0 = frozen
};

class ParamArena {
 public:
  // Register a parameter before finalize(); returns its index. A decaying parameter is pulled
  // toward decay_center by the L2 term; the optimizer steps it with lr x lr_scale.
  int add(const std::string& name, Shape shape, bool decays, float decay_center = 0.f, float lr_scale = 1.f);
  // Allocate values and grads (zeroed) once all parameters are registered.
  void finalize();

  std::size_t size() const { return total_; }
  const std::vector<ParamInfo>& infos() const { return infos_; }
  const ParamInfo& info(int id) const { return infos_[static_cast<std::size_t>(id)]; }
  int find(const std::string& name) const;  // -1 when absent

  float* values() { return values_.data(); }
  const float* values() const { return values_.data(); }
  float* grads() { return grads_.data(); }
  const float* grads() const { return grads_.data(); }
  float* value(int id) { return values() + info(id).offset; }
  const float* value(int id) const { return values() + info(id).offset; }
  float* grad(int id) { return grads() + info(id).offset; }
  const float* grad(int id) const { return grads() + info(id).offset; }
  void zero_grads();

 private:
  std::vector<ParamInfo> infos_;
  std::size_t total_ = 0;
  Tensor values_, grads_;  // [1, 1, 1, total], 64-byte aligned
  bool finalized_ = false;
};

}  // namespace lidarsim::nn
