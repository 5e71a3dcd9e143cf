#include <gtest/gtest.h>

#include <algorithm>
#include <limits>
#include <set>
#include <string>
#include <vector>

#include "common/plot.h"
#include "tests/support/image_checks.h"

using namespace lidarsim;

namespace {

constexpr Rgb kBackground{255, 255, 255}, kInk{0, 0, 0};

bool is(const Rgb& p, const Rgb& c) { return p.r == c.r && p.g == c.g && p.b == c.b; }

// The ink of one character at scale 1, as a string of '#' and '.' (one row after another).
std::string bitmap(char c) {
  Image im(kCellWidth, kLineHeight, kBackground);
  draw_text(im, 0, 0, std::string(1, c), kInk);
  std::string s;
  for (const Rgb& p : im.pixels) s += is(p, kInk) ? '#' : '.';
  return s;
}

void expect_ticks(double lo, double hi, int max_count, const std::vector<double>& expected) {
  const auto t = nice_ticks(lo, hi, max_count);
  ASSERT_EQ(t.size(), expected.size()) << lo << ".." << hi;
  for (size_t i = 0; i < t.size(); ++i) EXPECT_NEAR(t[i], expected[i], 1e-12) << lo << ".." << hi << " #" << i;
}

}  // namespace

TEST(Font, EveryPrintableGlyphButSpaceHasInkAndAllAreDistinct) {
  std::set<std::string> seen;
  for (char c = 32; c <= 126; ++c) {
    const std::string b = bitmap(c);
    EXPECT_EQ(b.find('#') != std::string::npos, c != ' ') << "'" << c << "'";
    EXPECT_TRUE(seen.insert(b).second) << "'" << c << "' looks like another glyph";
  }
  // Characters outside 32..126 draw a placeholder, distinct from every glyph.
  const std::string box = bitmap('\t');
  EXPECT_NE(box.find('#'), std::string::npos);
  EXPECT_EQ(seen.count(box), 0u);
  EXPECT_EQ(bitmap(static_cast<char>(200)), box);
}

TEST(Font, DescendersReachBelowTheBaselineAndCapitalsDoNot) {
  auto rows_with_ink = [](char c) {
    const std::string b = bitmap(c);
    std::set<int> rows;
    for (size_t i = 0; i < b.size(); ++i)
      if (b[i] == '#') rows.insert(static_cast<int>(i) / kCellWidth);
    return rows;
  };
  for (char c : std::string("gjpqy,_")) EXPECT_GE(*rows_with_ink(c).rbegin(), 7) << c;
  for (char c : std::string("AHXaxo0")) EXPECT_EQ(*rows_with_ink(c).rbegin(), 6) << c;
  EXPECT_EQ(*rows_with_ink('H').begin(), 0);
  EXPECT_EQ(*rows_with_ink('x').begin(), 2);  // x-height below the capitals
}

TEST(Font, DrawTextInksOnlyInsideItsBoxAndReachesItsEdges) {
  for (int scale : {1, 3}) {
    const std::string text = "Wq_|gM";  // ink in the first and last column, the top and the bottom row
    const int x = 7, y = 5, w = text_width(text, scale), h = text_height(scale);
    EXPECT_EQ(w, (6 * kCellWidth - 1) * scale);
    Image im(w + 20, h + 20, kBackground);
    draw_text(im, x, y, text, kInk, scale);
    int min_x = im.width, max_x = -1, min_y = im.height, max_y = -1;
    for (int py = 0; py < im.height; ++py)
      for (int px = 0; px < im.width; ++px)
        if (!is(im.at(px, py), kBackground)) {
          min_x = std::min(min_x, px), max_x = std::max(max_x, px);
          min_y = std::min(min_y, py), max_y = std::max(max_y, py);
        }
    EXPECT_EQ(min_x, x) << scale;
    EXPECT_EQ(max_x, x + w - 1) << scale;
    EXPECT_EQ(min_y, y) << scale;
    EXPECT_EQ(max_y, y + h - 1) << scale;
  }
  EXPECT_EQ(text_width("", 2), 0);
  Image small(4, 4, kBackground);
  draw_text(small, -3, -3, "WWW", kInk, 2);  // partly outside: clipped, no crash
}

TEST(Ticks, NiceTicksOnHandWorkedRanges) {
  // 0..0.93 with at most 6: steps 0.1 give 10 ticks, 0.2 gives 0, 0.2, ..., 0.8.
  expect_ticks(0, 0.93, 6, {0, 0.2, 0.4, 0.6, 0.8});
  // -0.37..0.12: step 0.05 gives 10, step 0.1 gives 5.
  expect_ticks(-0.37, 0.12, 6, {-0.3, -0.2, -0.1, 0, 0.1});
  // 12..87: step 10 gives 7 ticks (too many for 6), step 20 gives 4; with 8 allowed step 10.
  expect_ticks(12, 87, 6, {20, 40, 60, 80});
  expect_ticks(12, 87, 8, {20, 30, 40, 50, 60, 70, 80});
  expect_ticks(87, 12, 8, {20, 30, 40, 50, 60, 70, 80});  // reversed bounds
  // Ends that are multiples of the step are ticks themselves.
  expect_ticks(0, 1, 6, {0, 0.2, 0.4, 0.6, 0.8, 1});
  expect_ticks(2.5, 2.5, 6, {2.5});  // zero width
  EXPECT_TRUE(nice_ticks(0, std::numeric_limits<double>::infinity()).empty());
  // Three steps of 0.1 are the double nearest 0.3, not 0.30000000000000004.
  EXPECT_EQ(nice_ticks(0, 0.93, 10)[3], 0.3);
}

TEST(Ticks, LabelsUseTheFewestDigitsThatTellTicksApart) {
  EXPECT_EQ(tick_labels(nice_ticks(0, 0.93, 10)),
            (std::vector<std::string>{"0", "0.1", "0.2", "0.3", "0.4", "0.5", "0.6", "0.7", "0.8", "0.9"}));
  EXPECT_EQ(tick_labels({-0.3, -0.2, -0.1, 0, 0.1}), (std::vector<std::string>{"-0.3", "-0.2", "-0.1", "0", "0.1"}));
  EXPECT_EQ(tick_labels({20, 40, 60}), (std::vector<std::string>{"20", "40", "60"}));
  EXPECT_EQ(tick_labels({0.25}), (std::vector<std::string>{"0.25"}));
  EXPECT_EQ(tick_labels({-0.0, 0.05}), (std::vector<std::string>{"0", "0.05"}));  // no "-0"
  EXPECT_EQ(tick_labels({0, 0.5, 1, 1.5}), (std::vector<std::string>{"0", "0.5", "1", "1.5"}));
  // Uneven edges rounded to within 10% of the narrowest gap (0.9): one decimal tells them apart.
  EXPECT_EQ(tick_labels({1.2345, 2.1718, 5.5}, 0.1), (std::vector<std::string>{"1.2", "2.2", "5.5"}));
}

TEST(Chart, TwoBarsColourTheColumnsTheMappingGives) {
  ChartSpec spec;
  spec.width = 400, spec.height = 300, spec.scale = 1;
  spec.title = "two bars", spec.x_label = "x", spec.y_label = "y";
  spec.x_lo = 0, spec.x_hi = 4, spec.y_lo = 0, spec.y_hi = 10;
  Chart chart(spec);
  EXPECT_EQ(chart.y_lo(), 0);
  EXPECT_EQ(chart.y_hi(), 10);  // already whole tick steps: unchanged
  const int w = chart.right() - chart.left(), h = chart.bottom() - chart.top();
  ASSERT_GT(w, 100);
  ASSERT_GT(h, 100);
  // x = 1 sits a quarter of the way across, y = 5 half way up.
  const int x1 = chart.left() + (w + 2) / 4, x2 = chart.left() + (2 * w + 2) / 4, x3 = chart.left() + (3 * w + 2) / 4;
  const int y5 = chart.bottom() - (h + 1) / 2;
  EXPECT_EQ(chart.px(1), x1);
  EXPECT_EQ(chart.px(4), chart.right());
  EXPECT_EQ(chart.py(5), y5);
  EXPECT_EQ(chart.py(0), chart.bottom());

  const Rgb red{200, 0, 0}, blue{0, 0, 200};
  chart.bar(1, 2, 0, 5, red);
  chart.bar(2, 3, 0, 10, blue);
  const Image& im = chart.image();
  const int row = chart.bottom() - 1;  // lowest row of the plot area: both bars reach it
  EXPECT_FALSE(is(im.at(x1 - 1, row), red));
  EXPECT_TRUE(is(im.at(x1, row), red));
  EXPECT_TRUE(is(im.at(x2 - 1, row), red));
  EXPECT_TRUE(is(im.at(x2, row), blue));
  EXPECT_TRUE(is(im.at(x3 - 1, row), blue));
  EXPECT_FALSE(is(im.at(x3, row), blue));
  // Heights: the red bar's top row is y = 5; the blue one fills the plot area to its top row.
  EXPECT_TRUE(is(im.at(x1, y5), red));
  EXPECT_FALSE(is(im.at(x1, y5 - 1), red));
  EXPECT_TRUE(is(im.at(x2, chart.top()), blue));
  // Data never covers the axes: the x axis row and the y axis column keep their colour.
  EXPECT_FALSE(is(im.at(x2, chart.bottom()), blue));
  chart.bar(-1, 5, -1, 11, red);
  EXPECT_FALSE(is(chart.image().at(chart.left() - 1, row), red));
  EXPECT_FALSE(is(chart.image().at(x2, chart.bottom()), red));
  EXPECT_FALSE(is(chart.image().at(x2, chart.top() - 1), red));
}

TEST(Chart, AutoRangeGrowsToWholeStepsAndTheLegendAvoidsTheData) {
  ChartSpec spec;
  spec.width = 480, spec.height = 320, spec.scale = 1;
  spec.x_lo = 0, spec.x_hi = 10, spec.y_lo = 0.013, spec.y_hi = 0.87;
  Chart chart(spec);
  // The step depends on the plot's height (0.1 or 0.2 here); the ends are its next multiples out.
  EXPECT_EQ(chart.y_lo(), 0);
  EXPECT_TRUE(chart.y_hi() == 0.9 || chart.y_hi() == 1.0) << chart.y_hi();
  // Tall bars on the right half: the legend goes into the top-left corner.
  const Rgb green{0, 160, 0}, key{200, 0, 200};
  chart.bar(5, 10, 0, 1, green);
  chart.legend({{"series", key, Mark::box}});
  int key_x = -1;
  for (int y = 0; y < chart.image().height && key_x < 0; ++y)
    for (int x = 0; x < chart.image().width; ++x)
      if (is(chart.image().at(x, y), key)) {
        key_x = x;
        break;
      }
  ASSERT_GE(key_x, 0);
  EXPECT_LT(key_x, chart.px(5));
}

TEST(Chart, StepLineMarkerAndReferenceLineLandOnTheirPixels) {
  ChartSpec spec;
  spec.width = 400, spec.height = 300, spec.scale = 1;
  spec.x_lo = 0, spec.x_hi = 4, spec.y_lo = -10, spec.y_hi = 10;
  Chart chart(spec);
  const Rgb step{0, 120, 0}, ref{0, 0, 0}, dot{200, 0, 200};
  chart.step({0, 1, 2}, {5, -5}, step, 1);  // up to 5 over [0, 1), down to -5 over [1, 2), back to 0
  chart.hline(0, ref);
  chart.marker(3, 5, dot, 3);
  const Image& im = chart.image();
  EXPECT_TRUE(is(im.at(chart.px(0.5), chart.py(5)), step));
  EXPECT_FALSE(is(im.at(chart.px(0.5), chart.py(5) + 1), step));
  EXPECT_TRUE(is(im.at(chart.px(1.5), chart.py(-5)), step));
  EXPECT_TRUE(is(im.at(chart.px(1), chart.py(2)), step));  // the riser between the two bins
  EXPECT_TRUE(is(im.at(chart.px(2), chart.py(-2)), step));  // the drop back to the base
  EXPECT_FALSE(is(im.at(chart.px(2.5), chart.py(5)), step));
  EXPECT_TRUE(is(im.at(chart.px(3.5), chart.py(0)), ref));
  EXPECT_FALSE(is(im.at(chart.px(3.5), chart.py(0) - 1), ref));
  EXPECT_TRUE(is(im.at(chart.px(3) + 3, chart.py(5)), dot));
  EXPECT_FALSE(is(im.at(chart.px(3) + 4, chart.py(5)), dot));
}

TEST(Chart, TooSmallForItsMarginsStillDrawsSafely) {
  ChartSpec spec;
  spec.width = 30, spec.height = 20, spec.scale = 2;
  spec.title = "a title far wider than the image", spec.x_label = "x", spec.y_label = "y";
  Chart chart(spec);
  chart.bar(0, 1, 0, 1, {1, 2, 3});
  chart.step({0, 0.5, 1}, {0.2, 0.9}, {1, 2, 3});
  chart.hline(0.5, {1, 2, 3});
  chart.legend({{"legend", {1, 2, 3}, Mark::marker}});
  EXPECT_EQ(chart.image().pixels.size(), 600u);
}

using test::count_colour;

TEST(Annotate, MarginsAndCaptionBandsMoveThePictureWithoutChangingIt) {
  Image im(3, 2, {1, 2, 3});
  im.at(2, 1) = {9, 9, 9};
  const Image m = add_margins(im, 4, 5, 6, 7, {0, 0, 0});
  EXPECT_EQ(m.width, 13);
  EXPECT_EQ(m.height, 14);
  EXPECT_TRUE(is(m.at(4, 5), {1, 2, 3}));
  EXPECT_TRUE(is(m.at(6, 6), {9, 9, 9}));
  EXPECT_TRUE(is(m.at(3, 5), {0, 0, 0}));

  const TextStyle style;
  const Image c = add_caption_band(Image(300, 10, {1, 2, 3}), "range", ColourKey{"0", "70"}, style);
  const int band = band_height(style.scale);
  ASSERT_EQ(c.width, 300);
  ASSERT_EQ(c.height, 10 + band);
  EXPECT_EQ(count_colour(c, 0, band, 300, c.height, {1, 2, 3}), 300 * 10);  // the picture, all of it
  EXPECT_GT(count_colour(c, 0, 0, 100, band, style.ink), 30);                // the caption at the left
  EXPECT_GT(count_colour(c, 0, 0, 100, band, style.background), 100);
  // The key at the right: both ends of the colour map, between its two labels.
  EXPECT_GT(count_colour(c, 100, 0, 300, band, colormap_viridis(0)), 5);
  EXPECT_GT(count_colour(c, 100, 0, 300, band, colormap_viridis(1)), 5);
  EXPECT_GT(count_colour(c, c.width - band_pad(2) - text_width("70", 2), 0, 300, band, style.ink), 10);
}

TEST(Annotate, LegendsDrawEverySwatchAndLabelAndARowStopsAtItsEnd) {
  const TextStyle style;
  const Rgb red{200, 0, 0}, green{0, 200, 0}, blue{0, 0, 200};
  const std::vector<LegendEntry> entries{{"box", red}, {"line", green, Mark::line}, {"dot", blue, Mark::marker}};
  Image box(300, 120, style.background);
  const int w = legend_box_width(entries, 2), h = legend_box_height(entries, 2);
  draw_legend_box(box, 10, 10, entries, style);
  EXPECT_TRUE(is(box.at(10, 10), style.border));
  EXPECT_TRUE(is(box.at(10 + w - 1, 10 + h - 1), style.border));
  EXPECT_TRUE(is(box.at(10 + w, 10 + h), style.background));
  for (Rgb c : {red, green, blue}) EXPECT_GT(count_colour(box, 10, 10, 10 + w, 10 + h, c), 5);
  EXPECT_GT(count_colour(box, 10, 10, 10 + w, 10 + h, style.ink), 50);

  Image row(300, 30, style.background);
  EXPECT_EQ(draw_legend_row(row, 0, 5, entries, 300, style), 3);
  Image narrow(300, 30, style.background);
  EXPECT_EQ(draw_legend_row(narrow, 0, 5, entries, 70, style), 1);  // room for "[] box" (64 px) only
  EXPECT_EQ(count_colour(narrow, 0, 0, 300, 30, green), 0);
}

TEST(Annotate, ScaleBarsHaveRoundLengthsAndTheirLabelBelow) {
  EXPECT_EQ(round_down_nice(23.6), 20);
  EXPECT_EQ(round_down_nice(50), 50);
  EXPECT_EQ(round_down_nice(1000), 1000);
  EXPECT_EQ(round_down_nice(9.99), 5);
  EXPECT_EQ(round_down_nice(1), 1);
  EXPECT_DOUBLE_EQ(round_down_nice(0.7), 0.5);
  EXPECT_EQ(round_down_nice(0), 0);
  EXPECT_EQ(round_down_nice(-3), 0);
  EXPECT_EQ(round_down_nice(std::numeric_limits<double>::infinity()), 0);

  const TextStyle style;
  Image im(200, 60, style.background);
  draw_scale_bar(im, 10, 5, 100, "20 m", style);
  EXPECT_TRUE(is(im.at(10, 5), style.ink));    // left tick
  EXPECT_TRUE(is(im.at(109, 5), style.ink));   // right tick
  EXPECT_FALSE(is(im.at(110, 5), style.ink));  // exactly 100 px
  EXPECT_TRUE(is(im.at(60, 5 + 2 * 2), style.ink));  // the bar
  EXPECT_GT(count_colour(im, 10, 5 + 7 * 2, 110, 5 + scale_bar_height(2), style.ink), 30);  // "20 m"
}
