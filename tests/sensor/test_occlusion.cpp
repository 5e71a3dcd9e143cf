// Occlusion in the angular grid: hand-worked truck/car/lane cases.
#include <gtest/gtest.h>

#include <cmath>
#include <iostream>

#include "sensor/occlusion.h"

using namespace lidarsim::sensor;

namespace {
Object box(int id, double x, double y, double z, double l, double w, double h) {
  Object o;
  o.id = id;
  o.position = {x, y, z};
  o.size = {l, w, h};
  return o;
}
// Sensor 1.73 m above the road (KITTI), so the road is at z = -1.73 in the sensor frame.
constexpr double kGround = -1.73;
}  // namespace

TEST(Occlusion, RayBoxSlabTestHandWorked) {
  const RayBox b = RayBox::of(box(1, 10, 0, 0, 2, 2, 2));
  double t = 0;
  int axis = -2, sign = 0;
  ASSERT_TRUE(ray_box(b, {0, 0, 0}, {1, 0, 0}, 100, t, &axis, &sign));
  EXPECT_NEAR(t, 9, 1e-12);
  EXPECT_EQ(axis, 0);
  EXPECT_EQ(sign, -1);
  EXPECT_FALSE(ray_box(b, {0, 0, 0}, {0, 1, 0}, 100, t));
  EXPECT_FALSE(ray_box(b, {0, 0, 0}, {1, 0, 0}, 8.5, t));  // beyond t_max
  ASSERT_TRUE(ray_box(b, {10, 0, 0}, {1, 0, 0}, 100, t));  // from inside
  EXPECT_EQ(t, 0);
  // Rotated 45 deg: the corner points at the sensor, at 10 - sqrt(2).
  Object r = box(2, 10, 0, 0, 2, 2, 2);
  r.heading = std::atan(1.0);
  ASSERT_TRUE(ray_box(RayBox::of(r), {0, 0, 0}, {1, 0, 0}, 100, t));
  EXPECT_NEAR(t, 10 - std::sqrt(2.0), 1e-12);
}

TEST(Occlusion, CarFullyBehindTruckIsOccluded) {
  // Truck 3.5 m tall and 2.5 m wide at 15 m; a car (1.5 m tall, 1.8 m wide) at 30 m straight
  // behind it: every ray to the car passes through the truck first.
  std::vector<Object> objs = {box(1, 15, 0, kGround + 1.75, 8, 2.5, 3.5), box(2, 30, 0, kGround + 0.75, 4.5, 1.8, 1.5)};
  std::vector<LanePolyline> lanes;
  Occlusion occ;
  occ.apply(objs, lanes);
  EXPECT_NEAR(objs[0].visible_fraction, 1.0, 1e-12);
  EXPECT_GT(occ.footprint_cells()[1], 50);  // the car does cover cells...
  std::cout << "car fully behind the truck: visible fraction " << objs[1].visible_fraction << " of "
            << occ.footprint_cells()[1] << " cells\n";
  EXPECT_LT(objs[1].visible_fraction, 0.02);  // ...but none are its own (tolerance 0.02)
}

TEST(Occlusion, CarHalfBehindTruckIsAboutHalfVisible) {
  // The car at 30 m straight behind; the truck at 15 m shifted so its left edge is on the line
  // of sight to the car's centre: in angle it covers the car's right half. Tolerance 0.1: the
  // car's silhouette is not symmetric about its centre direction (we see its side at an angle)
  // and the grid quantises at 0.25 deg.
  const double car_y = 0, truck_w = 2.5;
  std::vector<Object> objs = {box(1, 15, car_y - truck_w / 2, kGround + 1.75, 8, truck_w, 3.5),
                              box(2, 30, car_y, kGround + 0.75, 4.5, 1.8, 1.5)};
  std::vector<LanePolyline> lanes;
  Occlusion occ;
  occ.apply(objs, lanes);
  std::cout << "car half behind the truck: visible fraction " << objs[1].visible_fraction << " ("
            << occ.visible_cells()[1] << " of " << occ.footprint_cells()[1] << " cells)\n";
  EXPECT_NEAR(objs[1].visible_fraction, 0.5, 0.1);
  EXPECT_NEAR(objs[0].visible_fraction, 1.0, 1e-12);
}

TEST(Occlusion, SeparatedObjectsAreFullyVisibleAndTinyObjectsJudgedByCentre) {
  std::vector<Object> objs = {box(1, 10, 5, kGround + 0.75, 4, 2, 1.5), box(2, 10, -5, kGround + 0.75, 4, 2, 1.5),
                              box(3, 100, 30, 0, 0.05, 0.05, 0.05)};
  std::vector<LanePolyline> lanes;
  Occlusion occ;
  occ.apply(objs, lanes);
  EXPECT_DOUBLE_EQ(objs[0].visible_fraction, 1.0);
  EXPECT_DOUBLE_EQ(objs[1].visible_fraction, 1.0);
  EXPECT_EQ(occ.footprint_cells()[2], 0);
  EXPECT_DOUBLE_EQ(objs[2].visible_fraction, 1.0);
}

TEST(Occlusion, LaneSegmentBehindCarIsGone) {
  // A lane marking straight ahead on the road from 2 to 60 m, a car (1.5 m tall) at 10-14.5 m
  // on it. Its roof (1.5 m above the road, x = 7.75..12.25 m) hides the road out to
  // 12.25 * 1.73 / (1.73 - 1.5) = 92 m: the lane survives before the car only.
  std::vector<Object> objs = {box(1, 10, 0, kGround + 0.75, 4.5, 1.8, 1.5)};
  std::vector<LanePolyline> lanes = {{1, LaneType::Solid, {}}, {2, LaneType::Solid, {}}};
  for (double x = 2; x <= 60.0001; x += 0.5) {
    lanes[0].points.emplace_back(x, 0, kGround);
    // Beside the car, 4 m to the left: its azimuth stays above the car's 6.6 deg out to 25 m.
    if (x <= 25) lanes[1].points.emplace_back(x, 4, kGround);
  }
  const auto n1 = lanes[1].points.size();
  Occlusion occ;
  occ.apply(objs, lanes);
  ASSERT_EQ(lanes.size(), 2u);
  double max_x = 0;
  for (const auto& p : lanes[0].points) max_x = std::max(max_x, p.x());
  EXPECT_LT(max_x, 7.8);            // nothing from the car to 58 m survives...
  EXPECT_GT(lanes[0].points.size(), 8u);  // ...but the part in front of it does
  for (const auto& p : lanes[0].points) EXPECT_FALSE(p.x() > 7.8 && p.x() < 58) << p.x();
  EXPECT_EQ(lanes[1].points.size(), n1);
}
