#pragma once
// Checks on pictures: how many pixels of a region have exactly one colour (a legend swatch, a
// caption's ink, a data cell), so that a test sees whether text and keys were drawn where meant.
#include "common/image.h"

namespace lidarsim::test {

// Pixels of colour c in columns [x0, x1) and rows [y0, y1).
inline long count_colour(const Image& im, int x0, int y0, int x1, int y1, Rgb c) {
  long n = 0;
  for (int y = y0; y < y1; ++y)
    for (int x = x0; x < x1; ++x) {
      const Rgb& p = im.at(x, y);
      n += p.r == c.r && p.g == c.g && p.b == c.b;
    }
  return n;
}

}  // namespace lidarsim::test
