// The simulation's pictures explain themselves: text in bands and a panel added around the data,
// which stays as it was (bird's-eye view and PGM rows of a frame built by hand).
#include <gtest/gtest.h>

#include "common/plot.h"
#include "infer/sim_outputs.h"
#include "infer/sim_pipeline.h"
#include "pgm/materials.h"
#include "tests/support/image_checks.h"

namespace lidarsim {
namespace {

using test::count_colour;

// Built by hand (no pipeline run): road returns on beam 5, a car on beam 3, one object reported.
infer::SimFrame hand_made_frame() {
  infer::SimFrame f;
  f.index = 3;
  f.time = 0.3;
  f.pgm = pgm::PolarGridMap(pgm::BeamLayout::uniform(8, 2, -24, 1024), {"range", "class", "material", "intensity", "mask"});
  for (int col = 0; col < 512; ++col) {
    const bool car = col < 100;
    const int row = car ? 3 : 5;
    f.pgm.at(f.pgm.channel_index("mask"), row, col) = 1;
    f.pgm.at(f.pgm.channel_index("range"), row, col) = car ? 10 : 20;
    f.pgm.at(f.pgm.channel_index("class"), row, col) = car ? pgm::cls::car : pgm::cls::road;
    f.pgm.at(f.pgm.channel_index("material"), row, col) = car ? pgm::material::car_paint : pgm::material::asphalt;
    f.pgm.at(f.pgm.channel_index("intensity"), row, col) = 0.5f;
  }
  sensor::Object o;
  o.position = {10, 0, 0};
  o.size = {4, 2, 1.5};
  f.sensor.objects = {o};
  f.reported = {{o, 0, false}};
  return f;
}

TEST(SimPictures, BevHasAHeaderAndALegendPanelBesideTheUntouchedMap) {
  const Image im = infer::bev_image(hand_made_frame(), 40);
  const int band = band_height(2), map = 800;
  ASSERT_EQ(im.height, band + map);
  ASSERT_GT(im.width, map + 200);  // the legend panel
  const Rgb ink{225, 225, 225};
  EXPECT_GT(count_colour(im, 0, 0, map, band, ink), 200) << "header: frame and time";
  // One swatch per kind of mark, in the map's colours, and their labels.
  for (Rgb c : {Rgb{60, 200, 60}, Rgb{30, 100, 30}, Rgb{230, 50, 50}, Rgb{255, 160, 0}, Rgb{230, 60, 230}})
    EXPECT_GT(count_colour(im, map, band, im.width, band + 300, c), 50) << int(c.r) << "," << int(c.g);
  EXPECT_GT(count_colour(im, map, band, im.width, band + 300, ink), 1000) << "legend labels";
  EXPECT_GT(count_colour(im, map, im.height - 60, im.width, im.height, ink), 100) << "scale bar";
  // The map, moved down by the band: the sensor's white cross and the object's boxes are in it.
  EXPECT_GT(count_colour(im, 380, band + 380, 420, band + 420, {255, 255, 255}), 30);
  EXPECT_GT(count_colour(im, 0, band, map, band + map, {230, 50, 50}), 50);
}

TEST(SimPictures, PgmRowsHaveCaptionsWithTheirScaleOrKeyBelowAHeader) {
  const infer::SimFrame f = hand_made_frame();
  const Image im = infer::pgm_image(f);
  const int band = band_height(2), row = 128, gap = 4;  // 8 beams, 16 px each
  ASSERT_EQ(im.width, 1024);
  ASSERT_EQ(im.height, band + 4 * (band + row) + 3 * gap);
  EXPECT_GT(count_colour(im, 0, 0, 1024, band, {0, 0, 0}), 200) << "header";
  const TextStyle style;
  for (int k = 0; k < 4; ++k) {
    const int top = band + k * (band + row + gap);
    EXPECT_GT(count_colour(im, 0, top, 300, top + band, style.ink), 100) << "caption of row " << k;
  }
  auto band_of = [&](int k, Rgb c) {
    const int top = band + k * (band + row + gap);
    return count_colour(im, 0, top, 1024, top + band, c);
  };
  // Range and intensity: a colour scale; class and material: a swatch for each id present.
  for (int k : {0, 3}) EXPECT_GT(band_of(k, colormap_viridis(0)), 5) << k;
  EXPECT_GT(band_of(1, colormap_category(pgm::cls::car)), 50);
  EXPECT_GT(band_of(1, colormap_category(pgm::cls::road)), 50);
  EXPECT_GT(band_of(2, colormap_category(pgm::material::car_paint)), 50);
  // The data: road returns at 20 m (the range scale's top) on beam 5 of the first row.
  const int range_top = 2 * band;
  EXPECT_EQ(count_colour(im, 100, range_top + 5 * 16, 512, range_top + 6 * 16, colormap_viridis(1)), 412 * 16);
}

}  // namespace
}  // namespace lidarsim
