#include "nn/conv3x3_amx_layout.h"

#include "nn/bf16_round.h"

namespace lidarsim::nn::detail::amx_layout {

Geom::Geom(int h_, int w_, int ci_) : h(h_), w(w_), ws(w_ + 2), ci(ci_) {
  mode = ci <= 16 ? Mode::narrow : Mode::wide;
  ps = ci <= 4 ? 4 : ci <= 8 ? 8 : (ci + kK - 1) / kK * kK;
  if (mode == Mode::narrow && ci > 8) ps = 16;
  q0 = ws + 1;
  q_end = static_cast<long>(h) * ws + w + 1;
  pixels = static_cast<long>(h + 2) * ws + kSlack;
  const auto off = [&](int dy, int dx) { return static_cast<long>(dy - 1) * ws + dx - 1; };
  if (mode == Mode::narrow) {
    const int span = kK / ps;  // taps per step
    row_steps = (3 + span - 1) / span;
    for (int dy = 0; dy < 3; ++dy)
      for (int k = 0; k < row_steps; ++k) aoff.push_back(off(dy, k * span) * ps);
  } else {
    for (int t = 0; t < 9; ++t)
      for (int k = 0; k < ps; k += kK) aoff.push_back(off(t / 3, t % 3) * ps + k);
  }
}

bool Geom::tap_channel(int s, int e, int* tap, int* c) const {
  if (mode == Mode::narrow) {
    const int dx = s % row_steps * (kK / ps) + e / ps;
    *tap = 3 * (s / row_steps) + dx, *c = e % ps;
    return dx < 3 && *c < ci;
  }
  const int blocks = ps / kK;
  *tap = s / blocks, *c = s % blocks * kK + e;
  return *c < ci;
}

// Weights [co, ci, 3, 3] -> B tiles [co block of 16][step]: 16 rows x 16 columns (output
// channels) of {bf16 product 2 r, product 2 r + 1} of the step, the pair layout tdpbf16ps
// multiplies with an A row of kK values; zeros past co and where the step has no product.
void pack_weights(std::uint32_t* dst, const float* w, int co, const Geom& g) {
  const int blocks = (co + kN - 1) / kN, steps = g.steps();
  const auto bits = [&](int o, int s, int e) {
    int t = 0, c = 0;
    if (o >= co || !g.tap_channel(s, e, &t, &c)) return 0u;
    return bf16_bits(w[(static_cast<std::size_t>(o) * g.ci + c) * 9 + t]);
  };
  for (int b = 0; b < blocks; ++b)
    for (int s = 0; s < steps; ++s)
      for (int r = 0; r < 16; ++r)
        for (int j = 0; j < kN; ++j) {
          const int o = b * kN + j;
          dst[((static_cast<std::size_t>(b) * steps + s) * 16 + r) * kN + j] =
              bits(o, s, 2 * r) | bits(o, s, 2 * r + 1) << 16;
        }
}

}  // namespace lidarsim::nn::detail::amx_layout
