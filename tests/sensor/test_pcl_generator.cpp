// PCL generator on geometry worked out by hand: one box, the road, a lane marking.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <set>

#include "common/angles.h"
#include "pgm/materials.h"
#include "sensor/frames.h"
#include "sensor/pcl_generator.h"

using namespace lidarsim::sensor;
namespace pgm = lidarsim::pgm;
using lidarsim::kDeg;

namespace {
// 16 rows at +7.5, 6.5, ..., -7.5 deg; 360 columns of 1 deg whose centres are at 0.5 + c deg.
pgm::BeamLayout one_degree_layout() { return pgm::BeamLayout::uniform(16, 7.5, -7.5, 360); }
}  // namespace

TEST(PclGenerator, SingleBoxHitsTheCellsAndRangesOfItsFrontFace) {
  // Sensor 5 m above the ego origin, no ground: a 1 x 2 x 2 m box whose front face is the square
  // x = 10, |y| <= 1, |z - 5| <= 1 (seen from the sensor: |y| <= 1, |z| <= 1 at x = 10).
  // A ray (el, az) hits it when 10 tan(az) <= 1 and 10 tan(el) / cos(az) <= 1: azimuth centres
  // +-0.5 .. +-5.5 deg (10 tan 5.5 = 0.963; 6.5 deg gives 1.14) -> columns 0..5 and 354..359;
  // elevations +-0.5 .. +-5.5 deg -> rows 2..13. 12 x 12 = 144 returns.
  const Pose mount = make_pose({0, 0, 5}, 0, 0, 0);
  PclConfig cfg;
  cfg.ground = false;
  PclGenerator gen(one_degree_layout(), mount, cfg);
  Object car;
  car.id = 42;
  car.cls = ObjectClass::Car;
  car.material = "car_paint";
  car.position = {10.5, 0, 5};
  car.size = {1, 2, 2};
  auto map = gen.make_map({"height"});
  const int n = gen.generate({car}, {}, map);
  EXPECT_EQ(n, 144);
  std::set<int> rows, cols;
  for (int r = 0; r < map.rows(); ++r)
    for (int c = 0; c < map.cols(); ++c)
      if (map.at(map.channel_index("mask"), r, c) > 0) {
        rows.insert(r);
        cols.insert(c);
        const double el = (7.5 - r) * kDeg, az = (c + 0.5) * kDeg;
        EXPECT_NEAR(map.at(map.channel_index("range"), r, c), 10 / (std::cos(el) * std::cos(az)), 1e-4);
        EXPECT_EQ(map.at(map.channel_index("object_id"), r, c), 42);
        EXPECT_EQ(map.at(map.channel_index("class"), r, c), pgm::cls::car);
        EXPECT_EQ(map.at(map.channel_index("material"), r, c), pgm::material::car_paint);
      }
  EXPECT_EQ(rows, (std::set<int>{2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13}));
  EXPECT_EQ(cols, (std::set<int>{0, 1, 2, 3, 4, 5, 354, 355, 356, 357, 358, 359}));
  // Centre cell: el 0.5, az 0.5 deg -> 10 / cos^2(0.5 deg) = 10.00076 m, height 10 tan(0.5 deg).
  EXPECT_NEAR(map.at(map.channel_index("range"), 7, 0), 10.00076, 1e-4);
  EXPECT_NEAR(map.at(map.channel_index("height"), 7, 0), 10 * std::tan(0.5 * kDeg), 1e-4);
  EXPECT_EQ(map.point_index()[7 * 360 + 0], 7 * 360);
  EXPECT_EQ(map.point_index()[0], -1);
}

TEST(PclGenerator, RotatedBoxAndYawedMountGiveTheSameRangeAsTheGeometry) {
  // Mount yawed 90 deg left: the sensor's column 0 looks along the ego's +y. A box at ego
  // (0, 10.5, 5) is then straight ahead of the sensor at 10 m.
  const Pose mount = make_pose({0, 0, 5}, 0, 0, 90 * kDeg);
  PclConfig cfg;
  cfg.ground = false;
  PclGenerator gen(one_degree_layout(), mount, cfg);
  Object o;
  o.id = 1;
  o.position = {0, 10.5, 5};
  o.size = {2, 1, 2};  // length along ego x, width 1 along ego y: front face at y = 10
  auto map = gen.make_map();
  EXPECT_EQ(gen.generate({o}, {}, map), 144);
  EXPECT_NEAR(map.at(map.channel_index("range"), 7, 0), 10.00076, 1e-4);
}

TEST(PclGenerator, GroundRangeAndLaneMarkingsAndDashes) {
  // Sensor 1.73 m above a flat road. Row 15 (-7.5 deg) meets it at 1.73 / sin(7.5 deg) =
  // 13.254 m, i.e. 13.14 m ahead horizontally.
  const Pose mount = make_pose({0, 0, 1.73}, 0, 0, 0);
  PclGenerator gen(one_degree_layout(), mount);
  auto map = gen.make_map();
  const double t = 1.73 / std::sin(7.5 * kDeg);
  const double horiz = t * std::cos(7.5 * kDeg);
  // Column 0's ray lands at y = horiz * sin(0.5 deg); put a solid marking there, parallel to x.
  const double y0 = horiz * std::sin(0.5 * kDeg);
  LanePolyline solid{1, LaneType::Solid, {{-50, y0, 0}, {50, y0, 0}}};
  // A dashed one through column 10's landing point, whose dash phase there is in the gap:
  // its polyline starts 3.5 m before the point, inside the 3 m paint / 6 m gap period's gap.
  const double az10 = 10.5 * kDeg, x10 = horiz * std::cos(az10), y10 = horiz * std::sin(az10);
  LanePolyline dashed_gap{2, LaneType::Dashed, {{x10 - 3.5, y10, 0}, {x10 + 50, y10, 0}}};
  // And one through column 20's landing point 1 m into a dash: painted.
  const double az20 = 20.5 * kDeg, x20 = horiz * std::cos(az20), y20 = horiz * std::sin(az20);
  LanePolyline dashed_paint{3, LaneType::Dashed, {{x20 - 1, y20, 0}, {x20 + 50, y20, 0}}};
  LanePolyline kerb{4, LaneType::RoadEdge, {{x20 - 1, -y20, 0}, {x20 + 50, -y20, 0}}};
  gen.generate({}, {solid, dashed_gap, dashed_paint, kerb}, map);
  const int cls = map.channel_index("class"), mat = map.channel_index("material");
  EXPECT_NEAR(map.at(map.channel_index("range"), 15, 0), t, 1e-4);
  EXPECT_EQ(map.at(cls, 15, 0), pgm::cls::lane_marking);
  EXPECT_EQ(map.at(mat, 15, 0), pgm::material::lane_paint);
  EXPECT_EQ(map.at(cls, 15, 10), pgm::cls::road);  // in the dash gap
  EXPECT_EQ(map.at(cls, 15, 20), pgm::cls::lane_marking);
  EXPECT_EQ(map.at(cls, 15, 339), pgm::cls::road);  // the kerb line is not paint
  EXPECT_EQ(map.at(mat, 15, 339), pgm::material::asphalt);
  EXPECT_EQ(map.at(cls, 15, 5), pgm::cls::road);    // 5 deg off the solid line: 1.1 m beside it
  EXPECT_EQ(map.at(map.channel_index("object_id"), 15, 5), -1);
  // Upward rows never reach the road (max range 120 m): no return.
  EXPECT_EQ(map.at(map.channel_index("mask"), 0, 0), 0);
}

TEST(PclGenerator, NearerBoxWinsAndBoxHidesTheRoad) {
  const Pose mount = make_pose({0, 0, 1.73}, 0, 0, 0);
  PclGenerator gen(one_degree_layout(), mount);
  Object near_box, far_box;
  near_box.id = 1;
  near_box.position = {8, 0, 0.75};
  near_box.size = {2, 2, 1.5};
  far_box.id = 2;
  far_box.position = {20, 0, 1.5};
  far_box.size = {2, 6, 3};
  auto map = gen.make_map();
  gen.generate({far_box, near_box}, {}, map);
  const int id = map.channel_index("object_id"), range = map.channel_index("range");
  // Row 10 (-2.5 deg), column 0: meets the near box's front (x = 7) at z = 1.73 - 7 tan 2.5 =
  // 1.42 m (< 1.5 m top): range 7 / (cos 2.5 cos 0.5) = 7.0070 m.
  EXPECT_EQ(map.at(id, 10, 0), 1);
  EXPECT_NEAR(map.at(range, 10, 0), 7 / (std::cos(2.5 * kDeg) * std::cos(0.5 * kDeg)), 1e-4);
  // Row 8 (-0.5 deg) passes over the near box (z at x = 9: 1.65 m) and hits the far one.
  EXPECT_EQ(map.at(id, 8, 0), 2);
  // Row 15 (-7.5 deg) would meet the road at 13.1 m but the near box is in the way.
  EXPECT_EQ(map.at(id, 15, 0), 1);
}

TEST(PclGenerator, SelectVisibleKeepsEgoBoxesOfVisibleIds) {
  std::vector<Object> ego(3), visible(2), out;
  for (int i = 0; i < 3; ++i) ego[i].id = i + 1;
  visible[0].id = 3;
  visible[1].id = 1;
  visible[1].visible_fraction = 0;  // fully occluded: not cast
  select_visible(ego, visible, out);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].id, 3);
}

TEST(PclGenerator, BeamsOutsideTheFieldOfViewAndBelowMinRangeReturnNothing) {
  // The box of the first test, seen by a sensor whose view ends at azimuth 2 deg on the left
  // and starts at -90: columns 0 and 1 (0.5, 1.5 deg) stay, 2..5 go; 354..359 stay.
  FieldOfView fov;
  fov.azimuth_min = -90 * kDeg;
  fov.azimuth_max = 2 * kDeg;
  fov.range_max = 100;
  PclConfig cfg = PclConfig::from_fov(fov);
  cfg.ground = false;
  Object o;
  o.position = {10.5, 0, 5};
  o.size = {1, 2, 2};
  PclGenerator gen(one_degree_layout(), make_pose({0, 0, 5}, 0, 0, 0), cfg);
  auto map = gen.make_map();
  EXPECT_EQ(gen.generate({o}, {}, map), 12 * 8);
  EXPECT_EQ(map.at(map.channel_index("mask"), 7, 1), 1);
  EXPECT_EQ(map.at(map.channel_index("mask"), 7, 2), 0);
  // A minimum range beyond the box's face: the box blocks the beams but returns nothing.
  fov.azimuth_min = -std::numbers::pi;
  fov.azimuth_max = std::numbers::pi;
  fov.range_min = 10.5;
  cfg = PclConfig::from_fov(fov);
  cfg.ground = false;
  PclGenerator near_blind(one_degree_layout(), make_pose({0, 0, 5}, 0, 0, 0), cfg);
  EXPECT_EQ(near_blind.generate({o}, {}, map), 0);
}

// Without the neighbourhood channels (a frame whose intensity is not predicted) incidence and
// depth discontinuity are 0 and every other channel is what a full generate gives; the next full
// generate on the same map estimates them again.
TEST(PclGenerator, SkippingTheNeighbourhoodChannelsChangesNoOtherChannel) {
  const Pose mount = make_pose({0, 0, 1.7}, 0, 0, 0);
  PclGenerator gen(one_degree_layout(), mount);
  Object car;
  car.id = 7;
  car.position = {12, 2, 0.75};
  car.size = {4.5, 1.8, 1.5};
  car.heading = 0.4;
  LanePolyline lane;
  lane.points = {{-20, -1.8, 0}, {60, -1.8, 0}};
  const std::vector<std::string> extra = {"incidence", "depth_discontinuity", "height"};
  auto full = gen.make_map(extra), lean = gen.make_map(extra);
  const int n_full = gen.generate({car}, {lane}, full);
  const int n_lean = gen.generate({car}, {lane}, lean, false);
  EXPECT_EQ(n_full, n_lean);
  EXPECT_GT(n_full, 100);
  double incidence = 0, discontinuity = 0;
  for (const auto& name : full.channel_names()) {
    const float* a = full.channel(name);
    const float* b = lean.channel(name);
    const bool skipped = name == "incidence" || name == "depth_discontinuity";
    for (std::size_t i = 0; i < full.cells(); ++i) {
      if (!skipped) {
        ASSERT_EQ(a[i], b[i]) << name << " cell " << i;
        continue;
      }
      ASSERT_EQ(b[i], 0.f) << name << " cell " << i;
      (name == "incidence" ? incidence : discontinuity) += std::abs(a[i]);
    }
  }
  EXPECT_GT(incidence, 0) << "a full generate estimates incidence (so the test can fail)";
  EXPECT_GT(discontinuity, 0) << "and depth discontinuities (the box's edges)";
  gen.generate({car}, {lane}, lean, false);
  gen.generate({car}, {lane}, lean);  // the same map, full again
  EXPECT_EQ(lean.data(), full.data());
  EXPECT_EQ(lean.point_index(), full.point_index());
}
