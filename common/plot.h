#pragma once
// Small charts for PNG reports people read on their own: a built-in bitmap font, round axis
// ticks, and a chart with axes, title, axis labels, legend and a few primitives (bars, step
// outline, lines, markers, reference lines). Knows nothing about what is plotted.
#include <string>
#include <string_view>
#include <vector>

#include "common/image.h"

namespace lidarsim {

// Bitmap font: printable ASCII 32..126, 5 x 9 glyphs (7 rows to the baseline, 2 for descenders)
// in a 6 x 11 cell, drawn at an integer scale. Other characters draw as a hollow box.
inline constexpr int kGlyphWidth = 5, kGlyphHeight = 9;
inline constexpr int kCellWidth = 6, kLineHeight = 11;

// Width of the ink box of `text` (no spacing after the last glyph); 0 for "".
int text_width(std::string_view text, int scale = 1);
// Height of the ink box of one line (descenders included).
int text_height(int scale = 1);
// Draws `text` with its ink box's top-left at (x, y); pixels outside the image are skipped.
void draw_text(Image& image, int x, int y, std::string_view text, Rgb colour, int scale = 1);

// Round tick values (steps of 1, 2 or 5 x 10^k) inside [lo, hi]: the smallest step that gives at
// most max_count ticks. {lo} when lo == hi; empty for non-finite input.
std::vector<double> nice_ticks(double lo, double hi, int max_count = 6);
// Labels with the fewest decimals that keep them distinct and each within max_error x (the
// smallest gap between neighbouring values) of its value, trailing zeros dropped ("0", "0.5", "1"):
// exact for nice ticks by default; a looser max_error (e.g. 0.1) rounds uneven values such as bin
// edges. Never "-0".
std::vector<std::string> tick_labels(const std::vector<double>& values, double max_error = 1e-6);

struct Tick {
  double value = 0;
  std::string label;
};

enum class Mark { box, line, marker, none };  // legend swatch: filled box, line, dot, text only
struct LegendEntry {
  std::string label;
  Rgb colour;
  Mark mark = Mark::box;
};

struct ChartSpec {
  int width = 960, height = 540, scale = 2;  // scale of all text
  std::string title, x_label, y_label;
  double x_lo = 0, x_hi = 1, y_lo = 0, y_hi = 1;
  // Empty: nice ticks over the range (the y range then grows to whole tick steps).
  std::vector<Tick> x_ticks, y_ticks;
};

// Draws the frame (title, y label above the axis, axes, ticks, gridlines, x label) on
// construction; data drawn afterwards is clipped to the plot area, so it never covers the axes.
class Chart {
 public:
  explicit Chart(ChartSpec spec);

  // Data -> pixel. An x interval [a, b) covers columns [px(a), px(b)); y grows upwards, so
  // [y0, y1) covers rows [py(y1), py(y0)). px(x_lo) = left(), px(x_hi) = right().
  int px(double x) const;
  int py(double y) const;
  // Plot area in pixels: columns [left, right), rows [top, bottom).
  int left() const { return left_; }
  int right() const { return right_; }
  int top() const { return top_; }
  int bottom() const { return bottom_; }
  double x_lo() const { return spec_.x_lo; }
  double x_hi() const { return spec_.x_hi; }
  double y_lo() const { return spec_.y_lo; }
  double y_hi() const { return spec_.y_hi; }

  // Filled rectangle in data coordinates; alpha < 1 blends with what is there.
  void bar(double x0, double x1, double y0, double y1, Rgb colour, double alpha = 1);
  // Outline of a histogram: heights[k] over [edges[k], edges[k + 1]), down to y = base at both ends.
  void step(const std::vector<double>& edges, const std::vector<double>& heights, Rgb colour, int thickness = 2,
            double base = 0);
  void line(double x0, double y0, double x1, double y1, Rgb colour, int thickness = 1);
  void marker(double x, double y, Rgb colour, int radius = 4);
  void hline(double y, Rgb colour, int thickness = 1);
  // Boxed legend in the plot-area corner that covers the least drawn data; draw it last.
  void legend(const std::vector<LegendEntry>& entries);
  // Shades [x0, x1) over the full height (e.g. a region that is not on the axis' scale).
  void band(double x0, double x1, Rgb colour);

  const Image& image() const { return image_; }

 private:
  void fill(int x0, int y0, int x1, int y1, Rgb colour, double alpha = 1);  // clipped to the plot area
  void segment(int x0, int y0, int x1, int y1, Rgb colour, int thickness);

  ChartSpec spec_;
  Image image_;
  int left_ = 0, right_ = 0, top_ = 0, bottom_ = 0;
};

// Text on pictures that are not charts (range images, maps): a caption band above an image,
// legends, colour keys and scale bars, so a picture explains itself without its Markdown caption.

// Light by default (dark ink on white); a dark picture passes a dark background and light ink.
struct TextStyle {
  Rgb ink{40, 40, 40}, background{255, 255, 255}, border{150, 150, 150};  // border: boxes, swatch outlines
  int scale = 2;
};
// A figure's header on grey, so it does not read as the caption of the row below it.
inline constexpr TextStyle kHeaderStyle{{0, 0, 0}, {225, 225, 225}};

// Fills [x0, x1) x [y0, y1), clipped to the image.
void fill_rect(Image& image, int x0, int y0, int x1, int y1, Rgb colour);
// `image` inside margins of `fill`: every pixel keeps its colour, moved by (left, top).
Image add_margins(const Image& image, int left, int top, int right, int bottom, Rgb fill);

// A band of one text line: band_height(scale) rows, the text's top band_pad(scale) below the band's.
int band_pad(int scale);
int band_height(int scale);

// "lo [bar] hi": the colour map from t = 0 (left) to 1 (right) between the values they stand for.
struct ColourKey {
  std::string lo, hi;
  Rgb (*colormap)(float) = colormap_viridis;
  int bar_width = 160;  // pixels
};
int colour_key_width(const ColourKey& key, int scale);
// Text top at y, left end at x.
void draw_colour_key(Image& image, int x, int y, const ColourKey& key, const TextStyle& style);

// `image` below a band of style.background with `caption` at its left (and `key` at its right).
Image add_caption_band(const Image& image, std::string_view caption, const TextStyle& style);
Image add_caption_band(const Image& image, std::string_view caption, const ColourKey& key, const TextStyle& style);
// First column of the band that the caption leaves free (a legend row can start there).
int caption_end(std::string_view caption, int scale);

// Entries side by side ("[] road  [] car"), text top at y, from x; an entry that would reach
// max_x and all after it are left out. Returns how many were drawn.
int draw_legend_row(Image& image, int x, int y, const std::vector<LegendEntry>& entries, int max_x,
                    const TextStyle& style);

// Boxed legend, one entry a line, top-left corner at (x, y).
int legend_box_width(const std::vector<LegendEntry>& entries, int scale);
int legend_box_height(const std::vector<LegendEntry>& entries, int scale);
void draw_legend_box(Image& image, int x, int y, const std::vector<LegendEntry>& entries, const TextStyle& style);

// A bar `length` pixels long with end ticks, `label` centred below it; (x, y) = its top-left.
int scale_bar_height(int scale);
void draw_scale_bar(Image& image, int x, int y, int length, std::string_view label, const TextStyle& style);
// The largest 1, 2 or 5 x 10^k not above max (a scale bar's length); 0 unless max > 0 and finite.
double round_down_nice(double max);

}  // namespace lidarsim
