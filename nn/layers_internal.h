#pragma once
// What the layer files (nn/conv_layers.cpp, nn/layers.cpp) share: shape checks, the test hook's
// fault switch and the sizes below which a parallel region costs more than it saves. Internal
// to nn/.
#include <string>

#include "common/error.h"
#include "nn/layers.h"

namespace lidarsim::nn::layers_internal {

inline bool fault(testhook::Fault f) { return testhook::fault == f; }

inline void ensure(Tensor& t, Shape s) {
  if (!(t.shape() == s)) t.resize(s);
}

inline void check_finite_shape(const Tensor& t, const char* op, const char* field) {
  if (t.numel() == 0) throw Error(std::string(op) + ": " + field + ": empty tensor " + t.shape().str());
}

// Below these sizes a parallel region costs more than it saves (and, on a loaded machine,
// spinning threads cost far more): run serially.
constexpr double kParallelFlops = 2e6;
constexpr std::size_t kParallelElems = 1 << 15;

}  // namespace lidarsim::nn::layers_internal
