// A gain over a window of azimuth (campaign family "gain over an azimuth window") and the
// scans' scenery. The candidate forms are cross-fitted over groups of held-out cells; with scans of
// one street the groups are columns (rotated folds), and an azimuth form fitted on some columns
// says nothing of the columns it never fitted. Where scans at different places exist (a drive),
// blocks of consecutive scans are the groups instead, and the window is named and cut; where they
// do not (one scan), the report says the data cannot decide on azimuth instead of ruling it out.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <map>
#include <iostream>

#include "data/planted_scans.h"
#include "data/reference_sensor.h"
#include "qualify/intensity/intensity.h"
#include "tests/support/reference_scans.h"

using namespace lidarsim;

namespace {

data::Dataset blocks_reference_geometry(int scans) {
  data::ReferenceScanOptions o;
  o.scans = scans;
  o.seed = 31;
  return lidarsim::testing::reference_scans(o, "loop_blocks");
}

// Each scan twice in a row: two scans of each place, as a drive gives (the same scenery at the same
// cells within a pair, other scenery in the next pair).
data::Dataset each_scan_twice(const data::Dataset& ds) {
  data::Dataset out;
  out.channels = ds.channels, out.source_format = ds.source_format;
  for (int n = 0; n < ds.size(); ++n)
    for (int k = 0; k < 2; ++k)
      out.append(ds.frame_pgm(n), ds.frames[n] + "/" + std::to_string(k),
                 n < static_cast<int>(ds.row_modes.size()) ? ds.row_modes[n] : "", ds.frame_place(n));
  return out;
}

data::PlantedScanDraw window_draw(const data::Dataset& geometry) {
  data::PlantedScanDraw d = data::draw_planted(data::PlantedScanFamily::AzimuthWindow, 5, geometry);
  d.effect.azimuth_start_deg = 200, d.effect.azimuth_width_deg = 60, d.effect.gain = 0.5;
  return d;
}

nlohmann::json blocks_lookup_loop(const data::Dataset& ds) {
  qualify::IntensityLoopOptions lo;
  lo.base_model = qualify::IntensityBase::Lookup;
  const auto j = qualify::loop_intensity(ds, lo);
  std::cout << "  cross-fit " << j["cross_fit"] << "\n  top " << j["ranking"][0].dump() << "\n  added "
            << j["added_effect"] << " via " << j["method"] << ", rmse " << j["rmse_before"] << " -> "
            << j["rmse_after"] << "\n";
  return j;
}

}  // namespace

TEST(LoopIntensityTimeBlocksStatistical, WindowOfAzimuthIsNamedAndCutOnBlocksOfScansAtDifferentPlaces) {
  const data::Dataset geometry = each_scan_twice(blocks_reference_geometry(4));
  ASSERT_EQ(geometry.size(), 8);
  const data::PlantedScanDraw draw = window_draw(geometry);
  const nlohmann::json j = blocks_lookup_loop(data::plant(geometry, draw));
  // Consecutive scans share their scenery half the time: not independent scans, but the blocks are.
  EXPECT_GE(j["scenery_correlation_between_scans"].get<double>(), 0.5);
  EXPECT_LT(j["scenery_correlation_between_time_blocks"].get<double>(), 0.2);
  EXPECT_NE(j["cross_fit"].get<std::string>().find("time block"), std::string::npos) << j["cross_fit"];
  const data::PlantedScore s = data::score_planted(draw, j);
  EXPECT_TRUE(s.named) << j["added_effect"] << "; ranking " << j["ranking"].dump();
  EXPECT_LE(s.excess_after, 0.7 * s.excess_before);
}

// One scan: the forms are cross-fitted over columns, which cannot judge azimuth; its forms are
// cross-fitted over classes x row blocks in the same columns instead, and a gain of the sensor
// there (every class, every row) is named and cut.
TEST(LoopIntensityTimeBlocks, OneScanNamesAWindowOfAzimuthAcrossClassesAndRowBlocks) {
  const data::Dataset geometry = blocks_reference_geometry(1);
  const data::PlantedScanDraw draw = window_draw(geometry);
  const nlohmann::json j = blocks_lookup_loop(data::plant(geometry, draw));
  ASSERT_TRUE(j.contains("azimuth_cross_fit")) << j["cross_fit"];
  EXPECT_NE(j["azimuth_cross_fit"].get<std::string>().find("classes x row blocks"), std::string::npos);
  const data::PlantedScore s = data::score_planted(draw, j);
  EXPECT_TRUE(s.named) << j["added_effect"] << "; ranking " << j["ranking"].dump();
  EXPECT_LE(s.excess_after, 0.7 * s.excess_before);
}

// Scenery that mimics a window: one class darker than its class's mean over 60 deg (a dark wall).
// Fitted on the other classes in the other rows, the window carries nothing of it.
TEST(LoopIntensityTimeBlocks, OneScanDarkObjectOfOneClassInAWindowAddsNothing) {
  const data::Dataset geometry = blocks_reference_geometry(1);
  const data::PlantedScanDraw control = data::draw_planted(data::PlantedScanFamily::Control, 5, geometry);
  data::Dataset ds = data::plant(geometry, control);
  const int ic = ds.channel_index("class"), iaz = ds.channel_index("azimuth");
  auto in_window = [](double az) { return std::fmod(az * 180 / M_PI + 720 - 200, 360) < 60; };
  // The class with the most returns in the window is the dark object.
  std::map<int, long> count;
  for (int r = 0; r < ds.rows(); ++r)
    for (int c = 0; c < ds.cols(); ++c)
      if (ds.mask.at(0, 0, r, c) > 0 && in_window(ds.pgm.at(0, iaz, r, c))) ++count[int(ds.pgm.at(0, ic, r, c))];
  ASSERT_GE(count.size(), 2u);
  const int dark = std::max_element(count.begin(), count.end(), [](auto& a, auto& b) { return a.second < b.second; })->first;
  long darkened = 0;
  for (int r = 0; r < ds.rows(); ++r)
    for (int c = 0; c < ds.cols(); ++c)
      if (ds.mask.at(0, 0, r, c) > 0 && in_window(ds.pgm.at(0, iaz, r, c)) && int(ds.pgm.at(0, ic, r, c)) == dark)
        ds.target.at(0, 0, r, c) *= 0.5f, ++darkened;
  EXPECT_GT(darkened, 500);
  const nlohmann::json j = blocks_lookup_loop(ds);
  EXPECT_TRUE(j["added_effect"].is_null()) << j["added_effect"] << "; ranking " << j["ranking"].dump();
}

// Where even classes x row blocks cannot decide (every return of one class), the report says so
// instead of ruling azimuth out.
TEST(LoopIntensityTimeBlocks, OneClassCannotDecideOnAzimuthAndSaysSo) {
  data::Dataset geometry = blocks_reference_geometry(1);
  const int ic = geometry.channel_index("class");
  for (int r = 0; r < geometry.rows(); ++r)
    for (int c = 0; c < geometry.cols(); ++c) geometry.pgm.at(0, ic, r, c) = 1;
  const nlohmann::json j = blocks_lookup_loop(data::plant(geometry, window_draw(geometry)));
  EXPECT_NE(j["added_effect"], "azimuth");
  int azimuth = 0;
  for (const auto& k : j["candidates_tested"])
    if (k["feature"] == "azimuth") {
      ++azimuth;
      EXPECT_EQ(k["decision"], "the data cannot decide") << k.dump();
      EXPECT_NE(k["reason"].get<std::string>().find("1 scan"), std::string::npos) << k["reason"];
      EXPECT_NE(k["reason"].get<std::string>().find("1 class"), std::string::npos) << k["reason"];
    }
  EXPECT_GT(azimuth, 0);
  for (const auto& r : j["ranking"]) EXPECT_NE(r["feature"], "azimuth");
  ASSERT_FALSE(j["undecided"].empty());
  EXPECT_EQ(j["undecided"][0]["feature"], "azimuth");
}
