#pragma once
// The layout the AMX kernel (nn/conv3x3_amx.cpp) works in: how a pixel's 9 x ci products are cut
// into tile steps, where the staged input and the packed weights hold them. Baseline code (no
// AVX-512, no AMX): the kernel file includes it before its target region.
#include <cstddef>
#include <cstdint>
#include <vector>

namespace lidarsim::nn::detail::amx_layout {

constexpr int kK = 32;            // bf16 per A tile row (64 bytes): the K of one tile step
constexpr int kN = 16;            // output channels per C tile
// Staged pixels past the last row: the widest pixel block (64) plus the up to 8 neighbours a
// narrow step reads.
constexpr int kSlack = 64 + 8;
// Image rows per task when an image has at least 2 kBand rows: such a task stages its rows (and
// the halo rows above and below) itself, into a buffer that stays in its core's L2 cache.
constexpr int kBand = 8;

// How the 9 taps x ci channels of a pixel's sum are cut into steps of kK products (one A tile
// row each, read at one pixel offset). With few channels, 32 per step would mostly multiply
// zeros, so the narrow mode packs pixels tighter:
//   wide    ci > 16: channels padded to ps = 32 k per pixel, steps (tap, 32-channel block);
//   narrow  ci <= 16: ps = 4, 8 or 16 channels per pixel, so the 32 bf16 read from pixel p are
//           32 / ps neighbours in a row, i.e. taps dx .. dx + 32 / ps - 1 of one dy (weights of
//           taps past dx 2 are zero): 3 steps (ci <= 8) or 6 (ci <= 16) instead of 9.
// (A tap-folded im2col staging of ci <= 3, one step, measured slower: its staging cost more
// than the two steps it saved.)
enum class Mode { wide, narrow };

// The padded pixel space of conv3x3_bf16 (rows of ws = w + 2, h + 2 rows, no front): pixel
// (y, x) is q = (y + 1) ws + x + 1; tap (dy, dx) of q reads q + (dy - 1) ws + dx - 1. The input
// is staged there as q-major bf16, ps values per pixel (zeros past ci); step s of pixel q reads
// kK values from element q ps + aoff[s].
struct Geom {
  int h, w, ws, ci;
  Mode mode;
  int ps, row_steps = 0;   // values per pixel; narrow: steps per tap row dy
  long q0, q_end, pixels;  // first valid q, one past the last, staged pixels per image
  std::vector<long> aoff;
  Geom(int h, int w, int ci);
  int steps() const { return static_cast<int>(aoff.size()); }
  // Which tap and input channel product e (0 .. kK - 1) of step s is; false for a zero.
  bool tap_channel(int s, int e, int* tap, int* c) const;
};

// Staged pixels of a band's buffer: kBand rows, the two halo rows, the row the last block's
// taps overrun into, and the slack.
inline std::size_t band_pixels(const Geom& g) { return static_cast<std::size_t>(kBand + 3) * g.ws + kSlack; }

// Weights [co, ci, 3, 3] -> B tiles [co block of 16][step], see the definition.
void pack_weights(std::uint32_t* dst, const float* w, int co, const Geom& g);

}  // namespace lidarsim::nn::detail::amx_layout
