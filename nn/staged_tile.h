#pragma once
// The write-out shared by the direct 3x3 kernels (fp32, nn/conv3x3.cpp; bf16, nn/conv3x3_bf16.cpp):
// both compute a chunk of padded pixel indices into an L1 staging tile, then copy its valid
// pixels out with bias and ReLU.
#include <algorithm>
#include <cstddef>

namespace lidarsim::nn::detail {

// Stage rows stage + j * stage_stride (j < channels) hold padded indices [qs, qe) of output
// channels o0 + j; padded index q = (y + 1) ws + x + 1 is pixel (y, x) of an h x w plane, so the
// borders and the chunk's ends are skipped. plane_of(o) gives channel o's [h, w] plane.
template <class PlaneOf>
inline void write_staged_tile(PlaneOf plane_of, const float* stage, int stage_stride, int o0, int channels,
                              const float* bias, bool relu, int qs, int qe, int h, int w, int ws) {
  const int r_first = std::max(0, qs / ws - 1), r_last = std::min(h - 1, qe / ws);
  for (int j = 0; j < channels; ++j) {
    const int o = o0 + j;
    const float bo = bias ? bias[o] : 0.f;
    float* op = plane_of(o);
    const float* st = stage + static_cast<std::size_t>(j) * stage_stride;
    for (int r = r_first; r <= r_last; ++r) {
      const int row_q = (r + 1) * ws + 1;
      const int x0 = std::max(0, qs - row_q), x1 = std::min(w, qe - row_q);
      if (x0 >= x1) continue;
      float* orow = op + static_cast<std::size_t>(r) * w;
      const float* srow = st + (row_q - qs);
      if (relu)
        for (int x = x0; x < x1; ++x) orow[x] = std::max(srow[x] + bo, 0.f);
      else
        for (int x = x0; x < x1; ++x) orow[x] = srow[x] + bo;
    }
  }
}

}  // namespace lidarsim::nn::detail
