#include "nn/receptive_field.h"

#include <algorithm>
#include <vector>

namespace lidarsim::nn {
namespace {

// Per position of one axis, the [lo, hi] input positions it depends on.
struct Span {
  std::vector<int> lo, hi;
  int size() const { return static_cast<int>(lo.size()); }
};

Span conv3(const Span& s) {
  Span o = s;
  for (int i = 0; i < s.size(); ++i)
    for (int d = -1; d <= 1; ++d) {
      const int j = i + d;
      if (j < 0 || j >= s.size()) continue;  // zero padding: depends on nothing
      o.lo[i] = std::min(o.lo[i], s.lo[j]);
      o.hi[i] = std::max(o.hi[i], s.hi[j]);
    }
  return o;
}

Span pool2(const Span& s) {
  Span o;
  for (int i = 0; 2 * i + 1 < s.size(); ++i) {
    o.lo.push_back(std::min(s.lo[2 * i], s.lo[2 * i + 1]));
    o.hi.push_back(std::max(s.hi[2 * i], s.hi[2 * i + 1]));
  }
  return o;
}

// Transposed 2x2 stride 2: output i comes from input i / 2; padded to `size`.
Span up2(const Span& s, int size) {
  Span o;
  for (int i = 0; i < size; ++i) {
    const int j = std::min(i / 2, s.size() - 1);
    o.lo.push_back(s.lo[j]);
    o.hi.push_back(s.hi[j]);
  }
  return o;
}

Span join(const Span& a, const Span& b) {
  Span o = a;
  for (int i = 0; i < a.size(); ++i) o.lo[i] = std::min(a.lo[i], b.lo[i]), o.hi[i] = std::max(a.hi[i], b.hi[i]);
  return o;
}

}  // namespace

int receptive_field_half_width(const UNetConfig& config) {
  // Long enough that the middle positions see no border: the reach is below 16 * 2^depth.
  const int n = 64 << config.depth;
  Span x;
  for (int i = 0; i < n; ++i) x.lo.push_back(i), x.hi.push_back(i);
  std::vector<Span> skips;
  Span cur = x;
  for (int l = 0; l <= config.depth; ++l) {
    cur = conv3(conv3(cur));
    if (l < config.depth) {
      skips.push_back(cur);
      cur = pool2(cur);
    }
  }
  for (int l = config.depth - 1; l >= 0; --l) {
    const Span up = up2(cur, skips[l].size());
    cur = conv3(conv3(join(skips[l], up)));
  }
  int half = 0;
  for (int i = n / 4; i < 3 * n / 4; ++i) half = std::max({half, i - cur.lo[i], cur.hi[i] - i});
  return half;
}

}  // namespace lidarsim::nn
