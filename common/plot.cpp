#include "common/plot.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <utility>

namespace lidarsim {

namespace {

// Glyph rows top to bottom, '#' = ink, separated by spaces; 7 rows reach the baseline, rows 8
// and 9 (optional) hold descenders. Designed for this project on a 5 x 9 grid.
constexpr std::array<const char*, 95> kFont = {
    "..... ..... ..... ..... ..... ..... .....",              // space
    "..#.. ..#.. ..#.. ..#.. ..#.. ..... ..#..",              // !
    ".#.#. .#.#. ..... ..... ..... ..... .....",              // "
    ".#.#. .#.#. ##### .#.#. ##### .#.#. .#.#.",              // #
    "..#.. .#### #.#.. .###. ..#.# ####. ..#..",              // $
    "##..# ##..# ...#. ..#.. .#... #..## #..##",              // %
    ".##.. #..#. #.#.. .#... #.#.# #..#. .##.#",              // &
    "..#.. ..#.. ..... ..... ..... ..... .....",              // '
    "...#. ..#.. .#... .#... .#... ..#.. ...#.",              // (
    ".#... ..#.. ...#. ...#. ...#. ..#.. .#...",              // )
    "..... ..#.. #.#.# .###. #.#.# ..#.. .....",              // *
    "..... ..#.. ..#.. ##### ..#.. ..#.. .....",              // +
    "..... ..... ..... ..... ..... .##.. ..#.. .#...",        // ,
    "..... ..... ..... ##### ..... ..... .....",              // -
    "..... ..... ..... ..... ..... .##.. .##..",              // .
    "....# ....# ...#. ..#.. .#... #.... #....",              // /
    ".###. #...# #..## #.#.# ##..# #...# .###.",              // 0
    "..#.. .##.. ..#.. ..#.. ..#.. ..#.. .###.",              // 1
    ".###. #...# ....# ...#. ..#.. .#... #####",              // 2
    "####. ....# ....# .###. ....# ....# ####.",              // 3
    "...#. ..##. .#.#. #..#. ##### ...#. ...#.",              // 4
    "##### #.... ####. ....# ....# #...# .###.",              // 5
    "..##. .#... #.... ####. #...# #...# .###.",              // 6
    "##### ....# ...#. ..#.. .#... .#... .#...",              // 7
    ".###. #...# #...# .###. #...# #...# .###.",              // 8
    ".###. #...# #...# .#### ....# ...#. .##..",              // 9
    "..... .##.. .##.. ..... .##.. .##.. .....",              // :
    "..... .##.. .##.. ..... .##.. ..#.. .#...",              // ;
    "...#. ..#.. .#... #.... .#... ..#.. ...#.",              // <
    "..... ..... ##### ..... ##### ..... .....",              // =
    ".#... ..#.. ...#. ....# ...#. ..#.. .#...",              // >
    ".###. #...# ....# ...#. ..#.. ..... ..#..",              // ?
    ".###. #...# #.### #.#.# #.##. #.... .####",              // @
    ".###. #...# #...# ##### #...# #...# #...#",              // A
    "####. #...# #...# ####. #...# #...# ####.",              // B
    ".###. #...# #.... #.... #.... #...# .###.",              // C
    "###.. #..#. #...# #...# #...# #..#. ###..",              // D
    "##### #.... #.... ####. #.... #.... #####",              // E
    "##### #.... #.... ####. #.... #.... #....",              // F
    ".###. #...# #.... #.### #...# #...# .####",              // G
    "#...# #...# #...# ##### #...# #...# #...#",              // H
    ".###. ..#.. ..#.. ..#.. ..#.. ..#.. .###.",              // I
    "..### ...#. ...#. ...#. ...#. #..#. .##..",              // J
    "#...# #..#. #.#.. ##... #.#.. #..#. #...#",              // K
    "#.... #.... #.... #.... #.... #.... #####",              // L
    "#...# ##.## #.#.# #.#.# #...# #...# #...#",              // M
    "#...# #...# ##..# #.#.# #..## #...# #...#",              // N
    ".###. #...# #...# #...# #...# #...# .###.",              // O
    "####. #...# #...# ####. #.... #.... #....",              // P
    ".###. #...# #...# #...# #.#.# #..#. .##.#",              // Q
    "####. #...# #...# ####. #.#.. #..#. #...#",              // R
    ".#### #.... #.... .###. ....# ....# ####.",              // S
    "##### ..#.. ..#.. ..#.. ..#.. ..#.. ..#..",              // T
    "#...# #...# #...# #...# #...# #...# .###.",              // U
    "#...# #...# #...# #...# #...# .#.#. ..#..",              // V
    "#...# #...# #...# #.#.# #.#.# #.#.# .#.#.",              // W
    "#...# #...# .#.#. ..#.. .#.#. #...# #...#",              // X
    "#...# #...# .#.#. ..#.. ..#.. ..#.. ..#..",              // Y
    "##### ....# ...#. ..#.. .#... #.... #####",              // Z
    ".###. .#... .#... .#... .#... .#... .###.",              // [
    "#.... #.... .#... ..#.. ...#. ....# ....#",              // backslash
    ".###. ...#. ...#. ...#. ...#. ...#. .###.",              // ]
    "..#.. .#.#. #...# ..... ..... ..... .....",              // ^
    "..... ..... ..... ..... ..... ..... ..... #####",        // _ (below the baseline: stays visible between letters)
    ".#... ..#.. ..... ..... ..... ..... .....",              // `
    "..... ..... .###. ....# .#### #...# .####",              // a
    "#.... #.... #.##. ##..# #...# #...# ####.",              // b
    "..... ..... .###. #.... #.... #...# .###.",              // c
    "....# ....# .##.# #..## #...# #...# .####",              // d
    "..... ..... .###. #...# ##### #.... .###.",              // e
    "..##. .#..# .#... ###.. .#... .#... .#...",              // f
    "..... ..... .#### #...# #...# #...# .#### ....# .###.",  // g
    "#.... #.... #.##. ##..# #...# #...# #...#",              // h
    "..#.. ..... .##.. ..#.. ..#.. ..#.. .###.",              // i
    "...#. ..... ..##. ...#. ...#. ...#. ...#. #..#. .##..",  // j
    "#.... #.... #..#. #.#.. ##... #.#.. #..#.",              // k
    ".##.. ..#.. ..#.. ..#.. ..#.. ..#.. .###.",              // l
    "..... ..... ##.#. #.#.# #.#.# #.#.# #.#.#",              // m
    "..... ..... #.##. ##..# #...# #...# #...#",              // n
    "..... ..... .###. #...# #...# #...# .###.",              // o
    "..... ..... ####. #...# #...# #...# ####. #.... #....",  // p
    "..... ..... .#### #...# #...# #...# .#### ....# ....#",  // q
    "..... ..... #.##. ##..# #.... #.... #....",              // r
    "..... ..... .###. #.... .###. ....# ####.",              // s
    ".#... .#... ###.. .#... .#... .#..# ..##.",              // t
    "..... ..... #...# #...# #...# #..## .##.#",              // u
    "..... ..... #...# #...# #...# .#.#. ..#..",              // v
    "..... ..... #...# #...# #.#.# #.#.# .#.#.",              // w
    "..... ..... #...# .#.#. ..#.. .#.#. #...#",              // x
    "..... ..... #...# #...# #...# #...# .#### ....# .###.",  // y
    "..... ..... ##### ...#. ..#.. .#... #####",              // z
    "...## ..#.. ..#.. ##... ..#.. ..#.. ...##",              // {
    "..#.. ..#.. ..#.. ..#.. ..#.. ..#.. ..#..",              // |
    "##... ..#.. ..#.. ...## ..#.. ..#.. ##...",              // }
    "..... ..... .#... #.#.# ...#. ..... .....",              // ~
};

using Glyph = std::array<std::uint8_t, kGlyphHeight>;  // one byte per row, bit 4 = leftmost column

// Parsed at compile time: a malformed row (not 5 wide, stray character, too many rows) does not compile.
constexpr Glyph parse_glyph(const char* s) {
  Glyph g{};
  int row = 0, col = 0;
  for (; *s; ++s) {
    if (*s == ' ') {
      if (col != kGlyphWidth) throw "glyph row is not 5 wide";
      ++row, col = 0;
      continue;
    }
    if ((*s != '.' && *s != '#') || col >= kGlyphWidth || row >= kGlyphHeight) throw "bad glyph";
    if (*s == '#') g[row] |= static_cast<std::uint8_t>(1 << (kGlyphWidth - 1 - col));
    ++col;
  }
  if (col != kGlyphWidth || row < 6) throw "glyph needs 7 to 9 rows";
  return g;
}

constexpr std::array<Glyph, 95> kGlyphs = [] {
  std::array<Glyph, 95> glyphs{};
  for (size_t i = 0; i < kFont.size(); ++i) glyphs[i] = parse_glyph(kFont[i]);
  return glyphs;
}();

constexpr Glyph kPlaceholder = parse_glyph("##### #...# #...# #...# #...# #...# #####");

const Glyph& glyph(char c) {
  const int code = static_cast<unsigned char>(c);
  return code >= 32 && code <= 126 ? kGlyphs[code - 32] : kPlaceholder;
}

void put(Image& im, int x, int y, Rgb c) {
  if (x >= 0 && y >= 0 && x < im.width && y < im.height) im.at(x, y) = c;
}

bool same(Rgb a, Rgb b) { return a.r == b.r && a.g == b.g && a.b == b.b; }

}  // namespace

int text_width(std::string_view text, int scale) {
  return text.empty() ? 0 : (static_cast<int>(text.size()) * kCellWidth - (kCellWidth - kGlyphWidth)) * scale;
}

int text_height(int scale) { return kGlyphHeight * scale; }

void draw_text(Image& image, int x, int y, std::string_view text, Rgb colour, int scale) {
  for (size_t i = 0; i < text.size(); ++i) {
    const Glyph& g = glyph(text[i]);
    const int x0 = x + static_cast<int>(i) * kCellWidth * scale;
    for (int row = 0; row < kGlyphHeight; ++row)
      for (int col = 0; col < kGlyphWidth; ++col) {
        if (!(g[row] >> (kGlyphWidth - 1 - col) & 1)) continue;
        for (int dy = 0; dy < scale; ++dy)
          for (int dx = 0; dx < scale; ++dx) put(image, x0 + col * scale + dx, y + row * scale + dy, colour);
      }
  }
}

namespace {

// A tick step m x 10^e with m in {1, 2, 5}; values are k x m / 10^-e for negative e, so 3 steps
// of 0.1 give the double nearest 0.3, not 0.30000000000000004.
struct Step {
  double m = 1;
  int e = 0;
  double value() const { return e < 0 ? m / std::pow(10.0, -e) : m * std::pow(10.0, e); }
  double at(long long k) const { return e < 0 ? k * m / std::pow(10.0, -e) : k * m * std::pow(10.0, e); }
  long long first(double lo) const { return static_cast<long long>(std::ceil(lo / value() - 1e-9)); }
  long long last(double hi) const { return static_cast<long long>(std::floor(hi / value() + 1e-9)); }
};

// Smallest step with at most max_count multiples in [lo, hi]; lo < hi, both finite.
Step nice_step(double lo, double hi, int max_count) {
  max_count = std::max(max_count, 1);
  int e = static_cast<int>(std::floor(std::log10((hi - lo) / max_count))) - 1;
  for (;; ++e)
    for (double m : {1.0, 2.0, 5.0}) {
      const Step s{m, e};
      if (s.last(hi) - s.first(lo) + 1 <= max_count) return s;
    }
}

std::vector<double> ticks_of(double lo, double hi, const Step& s) {
  std::vector<double> t;
  for (long long k = s.first(lo); k <= s.last(hi); ++k) t.push_back(k == 0 ? 0.0 : s.at(k));
  return t;
}

// Too many tick steps (a range far narrower than its magnitude) would not fit into a long long.
bool tickable(double lo, double hi) {
  return std::isfinite(lo) && std::isfinite(hi) && hi > lo && (hi - lo) > 1e-12 * std::max(std::abs(lo), std::abs(hi));
}

std::string format_fixed(double v, int decimals) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
  std::string s = buf;
  if (s.find('.') != std::string::npos) s.erase(s.find_last_not_of('0') + 1);  // "0.50" -> "0.5", "1.0" -> "1"
  if (s.back() == '.') s.pop_back();
  if (s == "-0") s = "0";
  return s;
}

}  // namespace

std::vector<double> nice_ticks(double lo, double hi, int max_count) {
  if (!std::isfinite(lo) || !std::isfinite(hi)) return {};
  if (lo > hi) std::swap(lo, hi);
  if (lo == hi) return {lo};
  if (!tickable(lo, hi)) return {lo, hi};
  return ticks_of(lo, hi, nice_step(lo, hi, max_count));
}

std::vector<std::string> tick_labels(const std::vector<double>& values, double max_error) {
  double gap = std::numeric_limits<double>::infinity(), mag = 0;
  for (size_t i = 0; i < values.size(); ++i) {
    mag = std::max(mag, std::abs(values[i]));
    for (size_t j = 0; j < i; ++j)
      if (values[i] != values[j]) gap = std::min(gap, std::abs(values[i] - values[j]));
  }
  if (!std::isfinite(gap)) gap = mag > 0 ? mag : 1;  // one distinct value: relative to itself
  const double tol = max_error * gap;
  std::vector<std::string> labels(values.size());
  for (int d = 0; d <= 15; ++d) {
    bool ok = true;
    for (size_t i = 0; i < values.size() && ok; ++i) {
      labels[i] = format_fixed(values[i], d);
      ok = !std::isfinite(values[i]) || std::abs(std::strtod(labels[i].c_str(), nullptr) - values[i]) <= tol;
      for (size_t j = 0; j < i && ok; ++j) ok = values[i] == values[j] || labels[i] != labels[j];
    }
    if (ok) return labels;
  }
  for (size_t i = 0; i < values.size(); ++i) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "%.15g", values[i]);
    labels[i] = buf;
  }
  return labels;
}

namespace {

constexpr Rgb kWhite{255, 255, 255}, kInk{40, 40, 40}, kAxis{90, 90, 90}, kGrid{228, 228, 228};

std::vector<Tick> auto_ticks(const std::vector<double>& values) {
  const auto labels = tick_labels(values);
  std::vector<Tick> t;
  for (size_t i = 0; i < values.size(); ++i) t.push_back({values[i], labels[i]});
  return t;
}

}  // namespace

Chart::Chart(ChartSpec spec) : spec_(std::move(spec)), image_(spec_.width, spec_.height, kWhite) {
  const int s = std::max(spec_.scale, 1), line = kLineHeight * s, pad = 4 * s, tick = 3 * s, body = 7 * s;
  if (!(spec_.x_hi > spec_.x_lo)) spec_.x_lo -= 0.5, spec_.x_hi = spec_.x_lo + 1;
  if (!(spec_.y_hi > spec_.y_lo)) spec_.y_lo -= 0.5, spec_.y_hi = spec_.y_lo + 1;

  // Vertical layout: title, y label (above the axis), plot, tick labels, x label.
  top_ = pad + (spec_.title.empty() ? 0 : line + pad) + (spec_.y_label.empty() ? 0 : line) + body / 2 + s;
  bottom_ = spec_.height - pad - (spec_.x_label.empty() ? 0 : line + pad) - line - tick - 1;
  const int plot_h = std::max(bottom_ - top_, 1);

  // y ticks first: their labels' width sets the left margin. Auto ranges grow to whole steps.
  if (spec_.y_ticks.empty() && tickable(spec_.y_lo, spec_.y_hi)) {
    const Step st = nice_step(spec_.y_lo, spec_.y_hi, std::max(2, plot_h / (3 * line)));
    const long long k0 = static_cast<long long>(std::floor(spec_.y_lo / st.value() + 1e-9));
    const long long k1 = static_cast<long long>(std::ceil(spec_.y_hi / st.value() - 1e-9));
    spec_.y_lo = k0 == 0 ? 0.0 : st.at(k0);
    spec_.y_hi = k1 == 0 ? 0.0 : st.at(k1);
    spec_.y_ticks = auto_ticks(ticks_of(spec_.y_lo, spec_.y_hi, st));
  }
  int label_w = 0;
  for (const Tick& t : spec_.y_ticks) label_w = std::max(label_w, text_width(t.label, s));
  left_ = pad + label_w + 2 * s + tick + 1;
  right_ = spec_.width - pad - 3 * kCellWidth * s;
  if (right_ <= left_) right_ = left_ + 1;
  if (spec_.x_ticks.empty() && tickable(spec_.x_lo, spec_.x_hi))
    spec_.x_ticks =
        auto_ticks(nice_ticks(spec_.x_lo, spec_.x_hi, std::max(2, (right_ - left_) / (9 * kCellWidth * s))));

  // Gridlines under everything, then axes, ticks and labels outside the plot area.
  for (const Tick& t : spec_.y_ticks) {
    const int y = py(t.value);
    if (y < top_ || y > bottom_) continue;
    if (y < bottom_) fill(left_, y, right_, y + 1, kGrid);
    for (int x = left_ - 1 - tick; x < left_ - 1; ++x) put(image_, x, y, kAxis);
    draw_text(image_, left_ - 1 - tick - 2 * s - text_width(t.label, s), y - body / 2, t.label, kInk, s);
  }
  // A label that would come within a character of one already drawn is left out (its tick
  // stays): ticks listed earlier win, so a caller puts the labels that matter most first.
  std::vector<std::pair<int, int>> drawn;
  for (const Tick& t : spec_.x_ticks) {
    const int x = px(t.value);
    if (x < left_ - 1 || x > right_) continue;
    for (int y = bottom_ + 1; y <= bottom_ + tick; ++y) put(image_, x, y, kAxis);
    const int w = text_width(t.label, s), x0 = x - w / 2, gap = kCellWidth * s;
    if (std::any_of(drawn.begin(), drawn.end(), [&](auto d) { return x0 < d.second + gap && d.first < x0 + w + gap; }))
      continue;
    draw_text(image_, x0, bottom_ + tick + 2 * s, t.label, kInk, s);
    drawn.emplace_back(x0, x0 + w);
  }
  for (int x = left_ - 1; x < right_; ++x) put(image_, x, bottom_, kAxis);
  for (int y = top_; y <= bottom_; ++y) put(image_, left_ - 1, y, kAxis);
  if (!spec_.x_label.empty())
    draw_text(image_, std::max(pad, (left_ + right_ - text_width(spec_.x_label, s)) / 2),
              bottom_ + tick + 2 * s + line + pad, spec_.x_label, kInk, s);
  if (!spec_.y_label.empty()) draw_text(image_, pad, top_ - body / 2 - s - line, spec_.y_label, kInk, s);
  if (!spec_.title.empty())
    draw_text(image_, std::max(pad, (left_ + right_ - text_width(spec_.title, s)) / 2), pad, spec_.title, {0, 0, 0}, s);
}

int Chart::px(double x) const {
  const double f = (x - spec_.x_lo) / (spec_.x_hi - spec_.x_lo);
  return left_ + static_cast<int>(std::lround(std::clamp(f, -100.0, 100.0) * (right_ - left_)));
}

int Chart::py(double y) const {
  const double f = (y - spec_.y_lo) / (spec_.y_hi - spec_.y_lo);
  return bottom_ - static_cast<int>(std::lround(std::clamp(f, -100.0, 100.0) * (bottom_ - top_)));
}

void Chart::fill(int x0, int y0, int x1, int y1, Rgb c, double alpha) {
  if (x0 > x1) std::swap(x0, x1);
  if (y0 > y1) std::swap(y0, y1);
  // Plot area and image both clip: a chart too small for its margins draws nothing, safely.
  for (int y = std::max({top_, y0, 0}); y < std::min({bottom_, y1, image_.height}); ++y)
    for (int x = std::max({left_, x0, 0}); x < std::min({right_, x1, image_.width}); ++x) {
      Rgb& p = image_.at(x, y);
      if (alpha >= 1) {
        p = c;
        continue;
      }
      auto mix = [&](std::uint8_t a, std::uint8_t b) {
        return static_cast<std::uint8_t>(std::lround(a * (1 - alpha) + b * alpha));
      };
      p = {mix(p.r, c.r), mix(p.g, c.g), mix(p.b, c.b)};
    }
}

void Chart::segment(int x0, int y0, int x1, int y1, Rgb c, int thickness) {
  // Bresenham with a square brush of side `thickness`.
  const int dx = std::abs(x1 - x0), dy = -std::abs(y1 - y0), sx = x0 < x1 ? 1 : -1, sy = y0 < y1 ? 1 : -1;
  const int h = thickness / 2;
  for (int err = dx + dy;;) {
    fill(x0 - h, y0 - h, x0 - h + thickness, y0 - h + thickness, c);
    if (x0 == x1 && y0 == y1) break;
    const int e2 = 2 * err;
    if (e2 >= dy) err += dy, x0 += sx;
    if (e2 <= dx) err += dx, y0 += sy;
  }
}

void Chart::bar(double x0, double x1, double y0, double y1, Rgb colour, double alpha) {
  fill(px(x0), py(std::max(y0, y1)), px(x1), py(std::min(y0, y1)), colour, alpha);
}

void Chart::step(const std::vector<double>& edges, const std::vector<double>& heights, Rgb colour, int thickness,
                 double base) {
  if (heights.empty() || edges.size() != heights.size() + 1) return;
  int x = px(edges[0]), y = py(base);
  for (size_t k = 0; k <= heights.size(); ++k) {
    const int ny = py(k < heights.size() ? heights[k] : base);
    segment(x, y, x, ny, colour, thickness);
    if (k == heights.size()) break;
    const int nx = px(edges[k + 1]);
    segment(x, ny, nx, ny, colour, thickness);
    x = nx, y = ny;
  }
}

void Chart::line(double x0, double y0, double x1, double y1, Rgb colour, int thickness) {
  segment(px(x0), py(y0), px(x1), py(y1), colour, thickness);
}

void Chart::marker(double x, double y, Rgb colour, int radius) {
  const int cx = px(x), cy = py(y);
  for (int dy = -radius; dy <= radius; ++dy)
    for (int dx = -radius; dx <= radius; ++dx)
      if (dx * dx + dy * dy <= radius * radius + radius) fill(cx + dx, cy + dy, cx + dx + 1, cy + dy + 1, colour);
}

void Chart::hline(double y, Rgb colour, int thickness) { segment(left_, py(y), right_ - 1, py(y), colour, thickness); }

void Chart::band(double x0, double x1, Rgb colour) { fill(px(x0), top_, px(x1), bottom_, colour); }

void Chart::legend(const std::vector<LegendEntry>& entries) {
  if (entries.empty()) return;
  const int s = std::max(spec_.scale, 1), line = kLineHeight * s, pad = 4 * s, swatch = 3 * kCellWidth * s;
  int label_w = 0;
  for (const LegendEntry& e : entries) label_w = std::max(label_w, text_width(e.label, s));
  const int w = pad + swatch + pad + label_w + pad, h = 2 * pad + static_cast<int>(entries.size()) * line - 2 * s;
  // Corners in order of preference; the one covering the fewest drawn (non-background) pixels wins.
  const int m = 2 * pad;
  const std::array<std::pair<int, int>, 4> corners{{{right_ - m - w, top_ + m},
                                                    {left_ + m, top_ + m},
                                                    {right_ - m - w, bottom_ - m - h},
                                                    {left_ + m, bottom_ - m - h}}};
  auto covered = [&](int x0, int y0) {
    long n = 0;
    for (int y = std::max(0, y0); y < std::min(image_.height, y0 + h); ++y)
      for (int x = std::max(0, x0); x < std::min(image_.width, x0 + w); ++x)
        n += !same(image_.at(x, y), kWhite) && !same(image_.at(x, y), kGrid);
    return n;
  };
  auto best = corners[0];
  long best_n = covered(best.first, best.second);
  for (const auto& c : corners)
    if (const long n = covered(c.first, c.second); n < best_n) best = c, best_n = n;
  const auto [x0, y0] = best;
  for (int y = y0; y < y0 + h; ++y)
    for (int x = x0; x < x0 + w; ++x)
      put(image_, x, y, y == y0 || y == y0 + h - 1 || x == x0 || x == x0 + w - 1 ? Rgb{170, 170, 170} : kWhite);
  for (size_t i = 0; i < entries.size(); ++i) {
    const LegendEntry& e = entries[i];
    const int ty = y0 + pad + static_cast<int>(i) * line, mid = ty + 7 * s / 2, sx = x0 + pad;
    for (int y = ty; y < ty + 7 * s; ++y)
      for (int x = sx; x < sx + swatch; ++x) {
        const int dx = x - (sx + swatch / 2), dy = y - mid;
        const bool ink = e.mark == Mark::box || (e.mark == Mark::line && std::abs(dy) <= s - 1) ||
                         (e.mark == Mark::marker && dx * dx + dy * dy <= 9 * s * s);
        if (ink) put(image_, x, y, e.colour);
      }
    draw_text(image_, sx + swatch + pad, ty, e.label, kInk, s);
  }
}

}  // namespace lidarsim

// ---- Text on pictures that are not charts.
namespace lidarsim {

namespace {

int swatch_width(int scale) { return 2 * kCellWidth * scale; }

// An entry's mark in [x, x + swatch_width) x [y, y + cap height). Boxes are outlined so that a
// white or black swatch still shows on a background of its own colour.
void draw_swatch(Image& image, int x, int y, const LegendEntry& e, const TextStyle& style) {
  const int s = std::max(style.scale, 1), w = swatch_width(s), h = 7 * s, mid = y + h / 2;
  switch (e.mark) {
    case Mark::box:
      fill_rect(image, x, y, x + w, y + h, style.border);
      fill_rect(image, x + 1, y + 1, x + w - 1, y + h - 1, e.colour);
      break;
    case Mark::line: fill_rect(image, x, mid - s / 2, x + w, mid - s / 2 + s, e.colour); break;
    case Mark::marker:
      for (int dy = -2 * s; dy <= 2 * s; ++dy)
        for (int dx = -2 * s; dx <= 2 * s; ++dx)
          if (dx * dx + dy * dy <= 4 * s * s + s) put(image, x + w / 2 + dx, mid + dy, e.colour);
      break;
    case Mark::none: break;
  }
}

}  // namespace

void fill_rect(Image& image, int x0, int y0, int x1, int y1, Rgb colour) {
  for (int y = std::max(y0, 0); y < std::min(y1, image.height); ++y)
    for (int x = std::max(x0, 0); x < std::min(x1, image.width); ++x) image.at(x, y) = colour;
}

Image add_margins(const Image& image, int left, int top, int right, int bottom, Rgb fill) {
  left = std::max(left, 0), top = std::max(top, 0);
  Image out(image.width + left + std::max(right, 0), image.height + top + std::max(bottom, 0), fill);
  for (int y = 0; y < image.height && image.width > 0; ++y)
    std::copy_n(&image.at(0, y), image.width, &out.at(left, top + y));
  return out;
}

int band_pad(int scale) { return 3 * std::max(scale, 1); }
int band_height(int scale) { return text_height(std::max(scale, 1)) + 2 * band_pad(scale); }

int colour_key_width(const ColourKey& key, int scale) {
  const int s = std::max(scale, 1);
  return text_width(key.lo, s) + key.bar_width + text_width(key.hi, s) + 2 * 3 * s;
}

void draw_colour_key(Image& image, int x, int y, const ColourKey& key, const TextStyle& style) {
  const int s = std::max(style.scale, 1), bar_x = x + text_width(key.lo, s) + 3 * s, w = key.bar_width;
  draw_text(image, x, y, key.lo, style.ink, s);
  fill_rect(image, bar_x, y, bar_x + w, y + 7 * s, style.border);  // 1-pixel outline around the gradient
  for (int i = 1; i + 1 < w; ++i)
    fill_rect(image, bar_x + i, y + 1, bar_x + i + 1, y + 7 * s - 1,
              key.colormap(static_cast<float>(i - 1) / static_cast<float>(std::max(w - 3, 1))));
  draw_text(image, bar_x + w + 3 * s, y, key.hi, style.ink, s);
}

Image add_caption_band(const Image& image, std::string_view caption, const TextStyle& style) {
  const int s = std::max(style.scale, 1);
  Image out = add_margins(image, 0, band_height(s), 0, 0, style.background);
  draw_text(out, band_pad(s), band_pad(s), caption, style.ink, s);
  return out;
}

Image add_caption_band(const Image& image, std::string_view caption, const ColourKey& key, const TextStyle& style) {
  Image out = add_caption_band(image, caption, style);
  const int s = std::max(style.scale, 1);
  draw_colour_key(out, out.width - band_pad(s) - colour_key_width(key, s), band_pad(s), key, style);
  return out;
}

int caption_end(std::string_view caption, int scale) {
  return band_pad(scale) + text_width(caption, std::max(scale, 1)) + 2 * kCellWidth * std::max(scale, 1);
}

int draw_legend_row(Image& image, int x, int y, const std::vector<LegendEntry>& entries, int max_x,
                    const TextStyle& style) {
  const int s = std::max(style.scale, 1), gap = 2 * kCellWidth * s, text_x = swatch_width(s) + 3 * s;
  int drawn = 0;
  for (const LegendEntry& e : entries) {
    const int w = text_x + text_width(e.label, s);
    if (x + w > max_x) break;
    draw_swatch(image, x, y, e, style);
    draw_text(image, x + text_x, y, e.label, style.ink, s);
    x += w + gap;
    ++drawn;
  }
  return drawn;
}

int legend_box_width(const std::vector<LegendEntry>& entries, int scale) {
  const int s = std::max(scale, 1);
  int label_w = 0;
  for (const LegendEntry& e : entries) label_w = std::max(label_w, text_width(e.label, s));
  return 3 * 4 * s + swatch_width(s) + label_w;
}

int legend_box_height(const std::vector<LegendEntry>& entries, int scale) {
  const int s = std::max(scale, 1);
  return 2 * 4 * s + static_cast<int>(entries.size()) * kLineHeight * s - 2 * s;  // no gap below the last line
}

void draw_legend_box(Image& image, int x, int y, const std::vector<LegendEntry>& entries, const TextStyle& style) {
  const int s = std::max(style.scale, 1), pad = 4 * s;
  const int w = legend_box_width(entries, s), h = legend_box_height(entries, s);
  fill_rect(image, x, y, x + w, y + h, style.border);
  fill_rect(image, x + 1, y + 1, x + w - 1, y + h - 1, style.background);
  for (size_t i = 0; i < entries.size(); ++i) {
    const int ty = y + pad + static_cast<int>(i) * kLineHeight * s;
    draw_swatch(image, x + pad, ty, entries[i], style);
    draw_text(image, x + 2 * pad + swatch_width(s), ty, entries[i].label, style.ink, s);
  }
}

int scale_bar_height(int scale) { return 7 * std::max(scale, 1) + text_height(scale); }

void draw_scale_bar(Image& image, int x, int y, int length, std::string_view label, const TextStyle& style) {
  const int s = std::max(style.scale, 1);
  fill_rect(image, x, y, x + s, y + 5 * s, style.ink);
  fill_rect(image, x + length - s, y, x + length, y + 5 * s, style.ink);
  fill_rect(image, x, y + 2 * s, x + length, y + 3 * s, style.ink);
  draw_text(image, x + (length - text_width(label, s)) / 2, y + 7 * s, label, style.ink, s);
}

double round_down_nice(double max) {
  if (!(max > 0) || !std::isfinite(max)) return 0;
  double p = std::pow(10.0, std::floor(std::log10(max)));
  if (p * 10 <= max) p *= 10;  // log10 can round just below a power of ten
  if (p > max) p /= 10;
  for (double m : {5.0, 2.0})
    if (m * p <= max) return m * p;
  return p;
}

}  // namespace lidarsim
