// Static scenery: read from the scenario (each bad field named by its JSON path), cast by the PCL
// generator with its own class and material, and part of the occlusion stage's depth test.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <string>

#include "common/angles.h"
#include "common/error.h"
#include "pgm/materials.h"
#include "sensor/frames.h"
#include "sensor/occlusion.h"
#include "sensor/pcl_generator.h"
#include "sensor/scenario.h"
#include "sensor/scenery.h"

using namespace lidarsim::sensor;
namespace pgm = lidarsim::pgm;
using lidarsim::kDeg;

namespace {

// A minimal scenario with `scenery` spliced in.
std::string with_scenery(const std::string& scenery) {
  return R"({"duration": 1, "rate_hz": 10,
    "sensor": {"mount": {"x": 0, "y": 0, "z": 1.73, "roll_deg": 0, "pitch_deg": 0, "yaw_deg": 0},
               "beams": {"rows": 16, "top_deg": 7.5, "bottom_deg": -7.5}, "columns": 360,
               "fov": {"horizontal_deg": [-180, 180], "vertical_deg": [-10, 10]}, "max_range": 80},
    "ego": {"states": [{"t": 0, "position": [0, 0, 0], "velocity": [0, 0, 0], "heading_deg": 0}]},
    "objects": [], "lanes": [], "scenery": )" +
         scenery + "}";
}

std::string scenery_error(const std::string& scenery) {
  try {
    parse_scenario(with_scenery(scenery), "street.json");
  } catch (const lidarsim::Error& e) {
    return e.what();
  }
  return "";
}

const char* kStreet = R"([
  {"kind": "box", "class": "building", "position": [20, -10], "size": [10, 6, 12], "heading_deg": 90},
  {"kind": "box", "class": "sidewalk", "material": "asphalt", "position": [0, -6, 0], "size": [40, 3, 0.12]},
  {"kind": "extrusion", "class": "fence", "points": [[0, 5], [10, 5], [10, 9]], "width": 0.1, "height": 1.2,
   "base": 0.12},
  {"kind": "extrusion", "class": "building", "points": [[30, 10], [40, 10], [40, 20]], "closed": true, "width": 0.3,
   "height": 9},
  {"kind": "tree", "position": [5, -6, 0.12], "trunk_diameter": 0.3, "trunk_height": 2.5, "crown_diameter": 4,
   "crown_height": 5},
  {"kind": "pole", "position": [8, -5.5], "height": 3, "diameter": 0.1,
   "sign": {"size": [0.6, 0.8], "heading_deg": 180}}
])";

}  // namespace

TEST(Scenery, ScenarioElementsBecomeBoxesWithTheirClassMaterialAndFoot) {
  const Scenario sc = parse_scenario(with_scenery(kStreet), "street.json");
  // box 1 + box 1 + fence 2 segments + closed triangle 3 + tree 5 + pole with sign 2.
  ASSERT_EQ(sc.scenery.size(), 14u);
  const SceneryBox& house = sc.scenery[0];
  EXPECT_EQ(house.class_id, pgm::cls::building);
  EXPECT_EQ(house.material_id, pgm::material::concrete);  // the class's default
  EXPECT_EQ(house.position, Eigen::Vector3d(20, -10, 6));  // the foot is on the road, z is the centre
  EXPECT_NEAR(house.heading, 90 * kDeg, 1e-12);
  EXPECT_EQ(house.element, 0);
  EXPECT_EQ(sc.scenery[1].material_id, pgm::material::asphalt);  // named material wins
  EXPECT_NEAR(sc.scenery[1].position.z(), 0.06, 1e-12);
  // Fence: segments reach width / 2 past their ends; the second turns 90 degrees.
  EXPECT_EQ(sc.scenery[2].class_id, pgm::cls::fence);
  EXPECT_EQ(sc.scenery[2].material_id, pgm::material::metal);
  EXPECT_NEAR(sc.scenery[2].size.x(), 10.1, 1e-12);
  EXPECT_NEAR(sc.scenery[2].position.z(), 0.12 + 0.6, 1e-12);
  EXPECT_NEAR(sc.scenery[3].heading, 90 * kDeg, 1e-12);
  EXPECT_EQ(sc.scenery[3].element, 2);
  // Closed triangle: its third segment joins the last point to the first.
  EXPECT_NEAR(sc.scenery[6].size.x(), std::hypot(10, 10) + 0.3, 1e-9);
  // Tree: a trunk up to 2.5 m above its foot, then the crown of vegetation.
  EXPECT_EQ(sc.scenery[7].class_id, pgm::cls::trunk);
  EXPECT_NEAR(sc.scenery[7].position.z(), 0.12 + 1.25, 1e-12);
  for (int i = 8; i < 12; ++i) EXPECT_EQ(sc.scenery[i].class_id, pgm::cls::vegetation) << i;
  EXPECT_NEAR(sc.scenery[11].position.z() + 0.5 * sc.scenery[11].size.z(), 0.12 + 2.5 + 5, 1e-12);
  // Pole and sign: the plate's top is the pole's top, on the side it faces (-x).
  EXPECT_EQ(sc.scenery[12].class_id, pgm::cls::pole);
  const SceneryBox& sign = sc.scenery[13];
  EXPECT_EQ(sign.class_id, pgm::cls::traffic_sign);
  EXPECT_EQ(sign.material_id, pgm::material::retroreflective_sign);
  EXPECT_NEAR(sign.position.z() + 0.5 * sign.size.z(), 3.0, 1e-12);
  EXPECT_LT(sign.position.x(), 8.0);
  // And the frame carries it.
  Frame f;
  sample_frame(sc, 0.0, f);
  EXPECT_EQ(f.scenery.size(), sc.scenery.size());
  EXPECT_TRUE(f.objects.empty());
}

TEST(Scenery, EachBadFieldIsAnErrorNamingTheFileAndItsJsonPath) {
  EXPECT_EQ(scenery_error(kStreet), "");
  EXPECT_EQ(scenery_error("[]"), "");
  const std::pair<const char*, const char*> cases[] = {
      {R"({"a": 1})", "scenery: must be an array"},
      {R"([{"class": "building"}])", "scenery[0].kind: missing"},
      {R"([{"kind": "cone"}])", "scenery[0].kind: must be \"box\", \"extrusion\", \"tree\" or \"pole\""},
      {R"([{"kind": "box", "class": "house", "position": [0, 0], "size": [1, 1, 1]}])", "scenery[0].class: class 'house'"},
      {R"([{"kind": "box", "class": "car", "position": [0, 0], "size": [1, 1, 1]}])",
       "scenery[0].class: 'car' is not a class of static scenery"},
      {R"([{"kind": "box", "class": "fence", "material": "wood", "position": [0, 0], "size": [1, 1, 1]}])",
       "scenery[0].material: material 'wood'"},
      {R"([{"kind": "box", "class": "fence", "position": [0], "size": [1, 1, 1]}])", "scenery[0].position: must be"},
      {R"([{"kind": "box", "class": "fence", "position": [0, 0], "size": [1, -1, 1]}])",
       "scenery[0].size[1]: must be positive"},
      {R"([{"kind": "box", "class": "fence", "position": [0, 0], "size": [1, 1, 1], "heading_deg": NaN}])",
       "scenery[0].heading_deg: must be a finite number"},
      {R"([{"kind": "extrusion", "class": "fence", "points": [[0, 0]], "width": 1, "height": 1}])",
       "scenery[0].points: must have at least 2 entries"},
      {R"([{"kind": "extrusion", "class": "fence", "points": [[0, 0], [1, 1]], "closed": true, "width": 1, "height": 1}])",
       "scenery[0].points: must have at least 3 entries"},
      {R"([{"kind": "extrusion", "class": "fence", "points": [[0, 0], [0, 0]], "width": 1, "height": 1}])",
       "scenery[0].points[1]: repeats the previous point"},
      {R"([{"kind": "extrusion", "class": "fence", "points": [[0, 0], [1, 0, 2]], "width": 1, "height": 1}])",
       "scenery[0].points[1]: must be an array of 2 numbers"},
      {R"([{"kind": "extrusion", "class": "fence", "points": [[0, 0], [1, 0]], "width": 0, "height": 1}])",
       "scenery[0].width: must be positive"},
      {R"([{"kind": "extrusion", "class": "fence", "points": [[0, 0], [1, 0]], "width": 1, "height": 1, "closed": 1}])",
       "scenery[0].closed: must be true or false"},
      {R"([{"kind": "tree", "position": [0, 0], "trunk_diameter": 0.3, "trunk_height": -2, "crown_diameter": 4,
            "crown_height": 4}])",
       "scenery[0].trunk_height: must be positive"},
      {R"([{"kind": "tree", "position": [0, 0], "trunk_diameter": 0.3, "trunk_height": 2, "crown_diameter": 4}])",
       "scenery[0].crown_height: missing"},
      {R"([{"kind": "pole", "position": [0, 0], "height": 2, "diameter": 0.1, "sign": {"size": [0.5, 3],
            "heading_deg": 0}}])",
       "scenery[0].sign.size[1]: must be positive and below the pole's height"},
      {R"([{"kind": "pole", "position": [0, 0], "height": 2, "diameter": 0.1, "sign": {"size": [0.5, 0.5]}}])",
       "scenery[0].sign.heading_deg: missing"},
  };
  for (const auto& [scenery, expected] : cases) {
    const std::string e = scenery_error(scenery);
    EXPECT_EQ(e.rfind("street.json: ", 0), 0u) << e;
    EXPECT_NE(e.find(expected), std::string::npos) << "scenery " << scenery << "\n  error: " << e;
  }
}

TEST(Scenery, ARayHitsAWallWithTheWallsClassAndMaterialAndNoObjectId) {
  // 16 rows of 1 degree around the horizon, 360 columns; sensor 1.73 m above the road. A
  // building wall (front face x = 10, |y| <= 5, 8 m tall) and a metal fence at y = 3 in front.
  const Pose mount = make_pose({0, 0, 1.73}, 0, 0, 0);
  PclGenerator gen(pgm::BeamLayout::uniform(16, 7.5, -7.5, 360), mount);
  std::vector<SceneryBox> scenery;
  add_scenery_box(scenery, {10.5, 0, 0}, {1, 10, 8}, 0, pgm::cls::building, pgm::material::concrete, 0);
  auto map = gen.make_map();
  gen.generate({}, scenery, {}, map);
  const int row = 7, col = 0;  // elevation +0.5, azimuth +0.5 deg: straight at the wall
  EXPECT_NEAR(map.at(map.channel_index("range"), row, col), 10 / (std::cos(0.5 * kDeg) * std::cos(0.5 * kDeg)), 1e-4);
  EXPECT_EQ(map.at(map.channel_index("class"), row, col), pgm::cls::building);
  EXPECT_EQ(map.at(map.channel_index("material"), row, col), pgm::material::concrete);
  EXPECT_EQ(map.at(map.channel_index("object_id"), row, col), -1);
  EXPECT_EQ(map.at(map.channel_index("mask"), row, col), 1);
  // Behind the sensor the road returns (row 15, -7.5 deg, meets it at 13.25 m).
  EXPECT_EQ(map.at(map.channel_index("class"), 15, 180), pgm::cls::road);
  // Without the scenery the same beam returns nothing (it rises over the road).
  auto bare = gen.make_map();
  gen.generate({}, {}, {}, bare);
  EXPECT_EQ(bare.at(bare.channel_index("mask"), row, col), 0);
}

TEST(Scenery, AWallHidesTheCarBehindItFromTheOcclusionStageAndTheRays) {
  // Sensor frame: a car 20 m ahead, a 3 m tall wall at 10 m between them, and a lane marking
  // running beside the car. The car's visible fraction falls from 1 to 0, the lane's points behind
  // the wall go, and the rays hit the wall, not the car.
  Object car;
  car.id = 1;
  car.position = {20, 0, 0.75 - 1.73};
  car.size = {4.5, 1.8, 1.5};
  std::vector<SceneryBox> wall;
  add_scenery_box(wall, {10, 0, -1.73}, {0.3, 6, 3}, 0, pgm::cls::building, pgm::material::concrete, 0);
  LanePolyline lane;
  lane.points = {{5, 2.5, -1.73}, {8, 2.5, -1.73}, {30, 2.5, -1.73}};  // beside the car, behind the wall
  Occlusion occ;
  std::vector<Object> alone{car}, hidden{car};
  std::vector<LanePolyline> lanes_alone{lane}, lanes_hidden{lane};
  occ.apply(alone, lanes_alone);
  occ.apply(hidden, lanes_hidden, wall);
  EXPECT_DOUBLE_EQ(alone[0].visible_fraction, 1.0);
  EXPECT_DOUBLE_EQ(hidden[0].visible_fraction, 0.0);
  ASSERT_EQ(lanes_hidden.size(), 1u);
  EXPECT_EQ(lanes_alone[0].points.size(), 3u);
  for (const auto& p : lanes_hidden[0].points) EXPECT_LT(p.x(), 10) << "a lane point behind the wall stayed";
  // A low wall (1 m) hides only the car's lower part.
  std::vector<SceneryBox> low;
  add_scenery_box(low, {10, 0, -1.73}, {0.3, 6, 1.0}, 0, pgm::cls::building, pgm::material::concrete, 0);
  std::vector<Object> partly{car};
  std::vector<LanePolyline> none;
  occ.apply(partly, none, low);
  EXPECT_GT(partly[0].visible_fraction, 0.1);
  EXPECT_LT(partly[0].visible_fraction, 0.9);

  // The rays (ego frame = sensor frame moved up by the mount): no cell returns the car.
  const Pose mount = make_pose({0, 0, 1.73}, 0, 0, 0);
  PclGenerator gen(pgm::BeamLayout::uniform(16, 7.5, -7.5, 360), mount);
  Object car_ego = car;
  car_ego.position.z() += 1.73;
  std::vector<SceneryBox> wall_ego = wall;
  wall_ego[0].position.z() += 1.73;
  auto map = gen.make_map();
  gen.generate({car_ego}, wall_ego, {}, map);
  int car_cells = 0, wall_cells = 0;
  for (int r = 0; r < map.rows(); ++r)
    for (int c = 0; c < map.cols(); ++c) {
      car_cells += map.at(map.channel_index("object_id"), r, c) == 1;
      wall_cells += static_cast<int>(map.at(map.channel_index("class"), r, c)) == pgm::cls::building;
    }
  EXPECT_EQ(car_cells, 0);
  EXPECT_GT(wall_cells, 100);
}

// The generator prunes by column, by slope and by distance: with a tilted mount and many random
// boxes (objects and scenery) it must give exactly what casting every ray at every box gives.
TEST(Scenery, PrunedCastEqualsCastingEveryBoxWithATiltedMount) {
  const Pose mount = make_pose({1.0, 0.2, 1.9}, 2 * kDeg, -3 * kDeg, 5 * kDeg);
  const auto layout = pgm::BeamLayout::uniform(24, 4, -20, 256);
  PclConfig cfg;
  cfg.max_range = 60;
  PclGenerator gen(layout, mount, cfg);
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(0, 1);
  std::vector<SceneryBox> scenery;
  std::vector<Object> objects;
  for (int i = 0; i < 60; ++i) {
    const Eigen::Vector3d foot(-70 + 140 * u(rng), -70 + 140 * u(rng), 0.2 * u(rng));
    const Eigen::Vector3d size(0.2 + 12 * u(rng), 0.2 + 12 * u(rng), 0.1 + 10 * u(rng));
    add_scenery_box(scenery, foot, size, 6.3 * u(rng), pgm::cls::building + i % 3, pgm::material::concrete, i);
  }
  for (int i = 0; i < 10; ++i) {
    Object o;
    o.id = 100 + i;
    o.position = {-30 + 60 * u(rng), -30 + 60 * u(rng), 0.75};
    o.size = {4.5, 1.8, 1.5};
    o.heading = 6.3 * u(rng);
    objects.push_back(o);
  }
  auto map = gen.make_map();
  gen.generate(objects, scenery, {}, map);
  int compared = 0, boxes_hit = 0;
  for (int r = 0; r < layout.rows(); ++r)
    for (int c = 0; c < layout.columns; ++c) {
      const double el = layout.elevations_rad[r], az = layout.azimuth_of_column(c);
      const Eigen::Vector3d d =
          mount.rotation * Eigen::Vector3d(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
      double best = cfg.max_range, t = 0;
      int cls = -1;
      if (d.z() < 0 && -mount.translation.z() / d.z() < best) {
        best = -mount.translation.z() / d.z();
        cls = pgm::cls::road;
      }
      for (const auto& o : objects)
        if (ray_box(RayBox::of(o), mount.translation, d, best, t) && t <= best) best = t, cls = pgm::cls::car;
      for (const auto& s : scenery) {
        RayBox b;
        b.centre = s.position;
        b.half = 0.5 * s.size;
        b.cos_h = std::cos(s.heading);
        b.sin_h = std::sin(s.heading);
        if (ray_box(b, mount.translation, d, best, t) && t <= best) best = t, cls = s.class_id;
      }
      const bool hit = cls >= 0;
      ASSERT_EQ(map.at(map.channel_index("mask"), r, c) > 0, hit) << r << "," << c;
      if (!hit) continue;
      ++compared;
      boxes_hit += cls != pgm::cls::road;
      EXPECT_NEAR(map.at(map.channel_index("range"), r, c), best, 1e-4) << r << "," << c;
      EXPECT_EQ(map.at(map.channel_index("class"), r, c), cls) << r << "," << c;
    }
  EXPECT_GT(boxes_hit, 1000);
  EXPECT_GT(compared, 3000);
}

TEST(Scenery, CullingDropsOnlyBoxesWhollyBeyondTheRange) {
  std::vector<SceneryBox> boxes;
  add_scenery_box(boxes, {75, 0, 0}, {2, 2, 2}, 0, pgm::cls::building, pgm::material::concrete, 0);   // 74 m
  add_scenery_box(boxes, {0, 75, 0}, {2, 12, 2}, 0, pgm::cls::building, pgm::material::concrete, 1);  // 69 m
  add_scenery_box(boxes, {0, 0, 0}, {300, 2, 2}, 0, pgm::cls::sidewalk, pgm::material::concrete, 2);  // 0 m
  EXPECT_NEAR(nearest_distance(boxes[0]), 74, 1e-12);
  cull_scenery(boxes, 70);
  ASSERT_EQ(boxes.size(), 2u);
  EXPECT_EQ(boxes[0].element, 1);
  EXPECT_EQ(boxes[1].element, 2);
}
