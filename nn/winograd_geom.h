#pragma once
// The tile geometry and by-phase plane layout of Winograd F(4x4, 3x3), shared by the AVX-512
// kernels (nn/winograd_tiles.h) and their AVX2 ports (nn/winograd_avx2.h). Plain integer code,
// outside any instruction-set region, so both compile it for the baseline.
#include <cstddef>

#include "nn/winograd.h"

namespace lidarsim::nn::detail::winograd_layout {

// The input is kept "by phase": for each padded row (yy = y + 1) and phase r in 0..3, entry tx
// holds pixel x = 4 tx + r - 1 (zero outside the image). Input tile (ty, tx) covers rows
// 4 ty - 1 .. 4 ty + 4 and columns 4 tx - 1 .. 4 tx + 4, i.e. phases 0..3 of tile tx and phases
// 0, 1 of tile tx + 1: adjacent tiles load as one unaligned vector each. Tiles are handled in
// blocks of nv 16-tile groups (one AVX-512 vector, two AVX2 vectors each).
struct Geom {
  int h, w, th, tw;
  int nv;         // 16-tile groups per block (1..3)
  int tb;         // tiles per block = 16 nv
  int blocks;     // blocks per tile row
  int len;        // floats per (row, phase) line: blocks * tb + 16
  int rows;       // padded rows: 4 th + 2
  std::size_t plane;  // floats per channel: rows * 4 * len
  Geom(int h_, int w_) : h(h_), w(w_), th((h_ + 3) / 4), tw((w_ + 3) / 4) {
    // Fewest junk tiles at the row end; ties go to the longer block (fewer weight reloads).
    int best = 3, best_waste = 1 << 30;
    for (int v = 3; v >= 1; --v) {
      const int t = 16 * v, waste = (tw + t - 1) / t * t - tw;
      if (waste < best_waste) best = v, best_waste = waste;
    }
    nv = best;
    tb = 16 * nv;
    blocks = (tw + tb - 1) / tb;
    len = blocks * tb + 16;
    rows = 4 * th + 2;
    plane = static_cast<std::size_t>(rows) * 4 * len;
  }
};

inline const float* plane_of(const PlaneSet& s, int img, int ch, std::size_t hw) {
  return ch < s.ca ? s.a + (static_cast<std::size_t>(img) * s.ca + ch) * hw
                   : s.b + (static_cast<std::size_t>(img) * s.cb + (ch - s.ca)) * hw;
}
inline float* plane_of(const OutPlaneSet& s, int img, int ch, std::size_t hw) {
  return ch < s.ca ? s.a + (static_cast<std::size_t>(img) * s.ca + ch) * hw
                   : s.b + (static_cast<std::size_t>(img) * s.cb + (ch - s.ca)) * hw;
}

}  // namespace lidarsim::nn::detail::winograd_layout
