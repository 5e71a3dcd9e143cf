// Scenario JSON reader: validation errors name the file and the JSON path; sampling
// interpolates keyframes.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <set>
#include <string>

#include "common/error.h"
#include "pgm/materials.h"
#include "sensor/scenario.h"
#include "tests/support/shared_data.h"

using namespace lidarsim::sensor;

namespace {

const char* kValid = R"({
  "name": "unit",
  "duration": 2.0, "rate_hz": 10,
  "sensor": {
    "mount": {"x": 1.0, "y": 0, "z": 1.73, "roll_deg": 0, "pitch_deg": 0, "yaw_deg": 0},
    "beams": {"rows": 32, "top_deg": 10, "bottom_deg": -20},
    "columns": 512,
    "fov": {"horizontal_deg": [-90, 90], "vertical_deg": [-20, 10]},
    "max_range": 80
  },
  "ego": {"states": [{"t": 0, "position": [0, 0, 0], "velocity": [5, 0, 0], "heading_deg": 0}]},
  "objects": [
    {"id": 1, "class": "Car", "size": [4.5, 1.8, 1.5],
     "states": [{"t": 0, "position": [20, 0, 0.75], "velocity": [2, 0, 0], "acceleration": [1, 0, 0], "heading_deg": 0},
                {"t": 2, "position": [26, 0, 0.75], "velocity": [4, 0, 0], "acceleration": [1, 0, 0], "heading_deg": 0}]},
    {"id": 2, "class": "Pedestrian", "size": [0.6, 0.6, 1.8], "material": "skin_fabric",
     "states": [{"t": 0.5, "position": [10, 5, 0.9], "velocity": [0, -1, 0], "heading_deg": -90},
                {"t": 1.5, "position": [10, 4, 0.9], "velocity": [0, -1, 0], "heading_deg": -90}]},
    {"id": 3, "class": "Truck", "size": [10, 2.5, 3.5],
     "states": [{"t": 0, "position": [40, -4, 1.75], "velocity": [0, 0, 0], "heading_deg": 170}]}
  ],
  "lanes": [{"id": 1, "type": "dashed", "points": [[0, 1.75], [100, 1.75]]}]
})";

// The error message of parsing `text` (empty when it parses).
std::string scenario_error_of(const std::string& text) {
  try {
    parse_scenario(text, "demo.json");
  } catch (const lidarsim::Error& e) {
    return e.what();
  }
  return "";
}

std::string replaced(std::string s, const std::string& from, const std::string& to) {
  const auto pos = s.find(from);
  EXPECT_NE(pos, std::string::npos) << from;
  return s.replace(pos, from.size(), to);
}

}  // namespace

TEST(Scenario, ValidFileReadsEveryField) {
  const Scenario sc = parse_scenario(kValid, "demo.json");
  EXPECT_EQ(sc.name, "unit");
  EXPECT_EQ(sc.frame_count(), 20);
  EXPECT_NEAR(sc.sensor.mount.translation.z(), 1.73, 1e-12);
  EXPECT_EQ(sc.sensor.beams.kind, "uniform");
  EXPECT_EQ(sc.sensor.beams.rows, 32);
  EXPECT_EQ(sc.sensor.beams.columns, 512);
  EXPECT_NEAR(sc.sensor.fov.azimuth_min, -std::numbers::pi / 2, 1e-12);
  EXPECT_NEAR(sc.sensor.fov.range_max, 80, 1e-12);
  ASSERT_EQ(sc.objects.size(), 3u);
  EXPECT_EQ(sc.objects[1].cls, ObjectClass::Pedestrian);
  EXPECT_EQ(sc.objects[0].material, "car_paint");  // default of the class
  EXPECT_NEAR(sc.objects[2].states[0].heading, 170 * std::numbers::pi / 180, 1e-12);
  ASSERT_EQ(sc.lanes.size(), 1u);
  EXPECT_EQ(sc.lanes[0].type, LaneType::Dashed);
  EXPECT_EQ(sc.lanes[0].points.size(), 201u);  // resampled to 0.5 m
}

TEST(Scenario, BeamLayoutsFromNameUniformSpecOrElevationList) {
  const Scenario hdl = parse_scenario(replaced(kValid, R"({"rows": 32, "top_deg": 10, "bottom_deg": -20})", R"("hdl64e")"), "demo.json");
  EXPECT_EQ(hdl.sensor.beams.layout().rows(), 64);
  const Scenario uni = parse_scenario(kValid, "demo.json");
  const auto ul = uni.sensor.beams.layout();
  EXPECT_EQ(ul.rows(), 32);
  EXPECT_EQ(ul.columns, 512);
  EXPECT_NEAR(ul.elevations_rad.front(), 10 * std::numbers::pi / 180, 1e-12);
  const Scenario list = parse_scenario(
      replaced(kValid, R"({"rows": 32, "top_deg": 10, "bottom_deg": -20})", R"({"elevations_deg": [-1, 3, 1]})"), "demo.json");
  const auto ll = list.sensor.beams.layout();
  ASSERT_EQ(ll.rows(), 3);
  EXPECT_NEAR(ll.elevations_rad[0], 3 * std::numbers::pi / 180, 1e-12);  // sorted, top first
  EXPECT_EQ(scenario_error_of(replaced(kValid, R"({"rows": 32, "top_deg": 10, "bottom_deg": -20})", R"({"elevations_deg": [1, 1]})")),
            "demo.json: sensor.beams.elevations_deg[1]: repeats the elevation 1");
  EXPECT_EQ(scenario_error_of(replaced(kValid, R"("top_deg": 10)", R"("top_deg": -30)")),
            "demo.json: sensor.beams.top_deg: must be above bottom_deg (-20), got -30");
}

TEST(Scenario, MissingFieldNamesItsPath) {
  const auto msg = scenario_error_of(replaced(kValid, R"("velocity": [0, -1, 0], "heading_deg": -90},
                {"t": 1.5)", R"("heading_deg": -90},
                {"t": 1.5)"));
  EXPECT_EQ(msg, "demo.json: objects[1].states[0].velocity: missing (required field)");
  EXPECT_EQ(scenario_error_of(replaced(kValid, R"("max_range": 80)", R"("range": 80)")),
            "demo.json: sensor.max_range: missing (required field)");
}

TEST(Scenario, NegativeSizeNamesItsPath) {
  EXPECT_EQ(scenario_error_of(replaced(kValid, "[10, 2.5, 3.5]", "[10, 2.5, -1.5]")),
            "demo.json: objects[2].size[2]: must be positive, got -1.5");
}

TEST(Scenario, NonFiniteNumbersNameTheirPath) {
  // NaN/Infinity as Python's json module writes them, and an overflowing literal.
  EXPECT_EQ(scenario_error_of(replaced(kValid, R"("position": [10, 4, 0.9])", R"("position": [10, NaN, 0.9])")),
            "demo.json: objects[1].states[1].position[1]: must be a finite number, got NaN");
  EXPECT_EQ(scenario_error_of(replaced(kValid, R"("yaw_deg": 0)", R"("yaw_deg": -Infinity)")),
            "demo.json: sensor.mount.yaw_deg: must be a finite number, got -Infinity");
  EXPECT_EQ(scenario_error_of(replaced(kValid, R"("duration": 2.0)", R"("duration": 1e999)")),
            "demo.json: duration: must be a finite number, got 1e999");
}

TEST(Scenario, UnknownClassAndMaterialAndLaneType) {
  const auto msg = scenario_error_of(replaced(kValid, R"("class": "Truck")", R"("class": "Spaceship")"));
  EXPECT_EQ(msg.rfind("demo.json: objects[2].class: unknown object class 'Spaceship'", 0), 0u) << msg;
  const auto mat = scenario_error_of(replaced(kValid, R"("material": "skin_fabric")", R"("material": "cheese")"));
  EXPECT_EQ(mat.rfind("demo.json: objects[1].material: ", 0), 0u) << mat;
  EXPECT_EQ(scenario_error_of(replaced(kValid, R"("type": "dashed")", R"("type": "dotted")")),
            "demo.json: lanes[0].type: must be \"solid\", \"dashed\" or \"road_edge\", got \"dotted\"");
}

TEST(Scenario, OtherBadInputs) {
  EXPECT_EQ(scenario_error_of(replaced(kValid, R"("id": 2,)", R"("id": 1,)")), "demo.json: objects[1].id: must be unique, got 1 twice");
  EXPECT_EQ(scenario_error_of(replaced(kValid, R"({"t": 1.5, "position": [10, 4, 0.9])", R"({"t": 0.5, "position": [10, 4, 0.9])")),
            "demo.json: objects[1].states[1].t: must be greater than the previous state's t (0.5), got 0.5");
  EXPECT_EQ(scenario_error_of(replaced(kValid, R"("size": [0.6, 0.6, 1.8])", R"("size": [0.6, 0.6])")),
            "demo.json: objects[1].size: must be an array of 3 numbers, got [0.6,0.6]");
  EXPECT_EQ(scenario_error_of("{\"duration\": 1,"), scenario_error_of("{\"duration\": 1,"));
  EXPECT_EQ(scenario_error_of("{\"duration\": 1,").rfind("demo.json: (json): not valid JSON", 0), 0u);
  try {
    read_scenario("/nonexistent/dir/x.json");
    FAIL() << "no error for a missing file";
  } catch (const lidarsim::Error& e) {
    EXPECT_EQ(std::string(e.what()), "/nonexistent/dir/x.json: (file): cannot open the scenario file");
  }
}

TEST(Scenario, ConstantAccelerationKeyframesAreReproducedExactly) {
  const Scenario sc = parse_scenario(kValid, "demo.json");
  // Car: x(t) = 20 + 2 t + t^2 / 2, so x(1) = 22.5, v(1) = 3, a = 1.
  KinematicState s;
  ASSERT_TRUE(sample_state(sc.objects[0].states, 1.0, s, false));
  EXPECT_NEAR(s.position.x(), 22.5, 1e-12);
  EXPECT_NEAR(s.velocity.x(), 3, 1e-12);
  EXPECT_NEAR(s.acceleration.x(), 1, 1e-12);
  ASSERT_TRUE(sample_state(sc.objects[0].states, 1.7, s, false));
  EXPECT_NEAR(s.position.x(), 20 + 2 * 1.7 + 0.5 * 1.7 * 1.7, 1e-12);
}

TEST(Scenario, SampledFrameHasEgoPoseAndOnlyExistingObjects) {
  const Scenario sc = parse_scenario(kValid, "demo.json");
  Frame f;
  sample_frame(sc, 0.2, f);  // pedestrian (0.5..1.5 s) not there yet
  ASSERT_EQ(f.objects.size(), 2u);
  EXPECT_EQ(f.objects[0].id, 1);
  EXPECT_EQ(f.objects[1].id, 3);
  EXPECT_NEAR(f.ego_in_map.translation.x(), 1.0, 1e-12);  // ego at 5 m/s, single keyframe
  sample_frame(sc, 1.0, f);
  ASSERT_EQ(f.objects.size(), 3u);
  EXPECT_EQ(f.objects[1].id, 2);
  EXPECT_NEAR(f.objects[1].position.y(), 4.5, 1e-12);
  EXPECT_EQ(f.objects[1].cls, ObjectClass::Pedestrian);
  EXPECT_NEAR(f.objects[2].position.x(), 40, 1e-12);  // single keyframe, at rest: always there
  EXPECT_EQ(f.lanes.size(), 1u);
}

TEST(Scenario, HeadingInterpolatesAlongTheShorterArc) {
  std::vector<KinematicState> st(2);
  st[0].t = 0;
  st[0].heading = 170 * std::numbers::pi / 180;
  st[1].t = 1;
  st[1].heading = -170 * std::numbers::pi / 180;
  KinematicState s;
  ASSERT_TRUE(sample_state(st, 0.5, s, false));
  EXPECT_NEAR(std::abs(s.heading), std::numbers::pi, 1e-12);
}

TEST(Scenario, BundledDemoScenarioReads) {
  const auto path = lidarsim::testing::source_dir() / "data/scenarios/demo_urban.json";
  const Scenario sc = read_scenario(path);
  EXPECT_EQ(sc.frame_count(), 100);  // 10 s at 10 Hz
  EXPECT_GE(sc.objects.size(), 8u);
  EXPECT_GE(sc.lanes.size(), 3u);
  // A street: buildings, sidewalks, vegetation, poles and signs among its scenery.
  std::set<int> scenery_classes;
  for (const auto& b : sc.scenery) scenery_classes.insert(b.class_id);
  for (int c : {lidarsim::pgm::cls::building, lidarsim::pgm::cls::sidewalk, lidarsim::pgm::cls::vegetation,
                lidarsim::pgm::cls::trunk, lidarsim::pgm::cls::pole, lidarsim::pgm::cls::traffic_sign,
                lidarsim::pgm::cls::fence, lidarsim::pgm::cls::terrain})
    EXPECT_TRUE(scenery_classes.count(c)) << lidarsim::pgm::class_name(c);
}

#include <map>
#include <set>

#include "sensor/frames.h"
#include "sensor/occlusion.h"
#include "sensor/scenery.h"

// The bundled demo must exercise every stage: every road-user class, an object hidden for a
// while (visible fraction < 0.1 for >= 5 consecutive frames after and/or before being seen at
// > 0.5), an object leaving the field of view for good, and lanes left after occlusion (by the
// objects and the street's scenery).
TEST(Scenario, BundledDemoExercisesEveryStage) {
  const Scenario sc = read_scenario(lidarsim::testing::source_dir() / "data/scenarios/demo_urban.json");
  std::set<ObjectClass> classes;
  for (const auto& o : sc.objects) classes.insert(o.cls);
  for (auto c : {ObjectClass::Car, ObjectClass::Truck, ObjectClass::Pedestrian, ObjectClass::Cyclist})
    EXPECT_TRUE(classes.count(c)) << to_string(c);

  Frame map, ego, sensor;
  Occlusion occ(OcclusionConfig::for_fov(sc.sensor.fov));
  std::map<int, std::string> timeline;  // per object: one char per frame
  for (const auto& o : sc.objects) timeline[o.id] = std::string(sc.frame_count(), ' ');
  for (int k = 0; k < sc.frame_count(); ++k) {
    sample_frame(sc, sc.frame_time(k), map);
    map_to_ego(map, ego);
    ego_to_sensor(ego, sc.sensor.mount, sensor);
    for (const auto& o : sensor.objects) timeline[o.id][k] = '-';  // exists, out of view
    apply_fov(sensor.objects, sc.sensor.fov);
    apply_fov_to_lanes(sensor.lanes, sc.sensor.fov);
    cull_scenery(sensor.scenery, sc.sensor.fov.range_max);
    occ.apply(sensor.objects, sensor.lanes, sensor.scenery);
    for (const auto& o : sensor.objects)
      timeline[o.id][k] = o.visible_fraction > 0.5 ? '#' : (o.visible_fraction < 0.1 ? '.' : '+');
    EXPECT_GE(sensor.lanes.size(), 2u) << "frame " << k;
  }
  bool hidden_for_a_while = false, leaves_view = false;
  for (const auto& [id, line] : timeline) {
    std::cout << "object " << id << (id < 10 ? " " : "") << " |" << line << "|\n";
    const auto seen = line.find('#');
    if (line.find(".....") != std::string::npos && seen != std::string::npos) hidden_for_a_while = true;
    const auto last_seen = line.find_last_of("#+.");
    if (last_seen != std::string::npos && last_seen + 1 < line.size() && line.find_first_not_of('-', last_seen + 1) == std::string::npos)
      leaves_view = true;
  }
  std::cout << "(# visible > 0.5, + partly, . hidden < 0.1, - exists but outside the field of view)\n";
  EXPECT_TRUE(hidden_for_a_while);
  EXPECT_TRUE(leaves_view);
}

// The sampling cursor only saves the search for the keyframe interval: forwards at the frame
// times, on keyframe times exactly, backwards and in jumps it gives bit for bit the frames
// sampled without it.
TEST(Scenario, SampleFrameWithACursorEqualsSamplingWithoutOneInAnyOrder) {
  const Scenario sc = read_scenario(lidarsim::testing::source_dir() / "data/scenarios/demo_urban.json");
  std::vector<double> times;
  for (int k = 0; k < sc.frame_count(); ++k) times.push_back(sc.frame_time(k));
  for (const auto& o : sc.objects)
    for (const auto& s : o.states) times.push_back(s.t);  // exactly on keyframes, out of order
  for (int k = sc.frame_count() - 1; k >= 0; k -= 3) times.push_back(sc.frame_time(k) + 0.013);
  times.push_back(-1.0);
  times.push_back(sc.duration + 5);
  SampleCursor cursor;
  Frame with, without;
  int objects_seen = 0;
  for (double t : times) {
    sample_frame(sc, t, with, &cursor);
    sample_frame(sc, t, without);
    ASSERT_EQ(with.objects.size(), without.objects.size()) << "t " << t;
    EXPECT_EQ(with.ego_in_map.translation, without.ego_in_map.translation) << "t " << t;
    EXPECT_EQ(with.ego_in_map.rotation, without.ego_in_map.rotation) << "t " << t;
    for (std::size_t i = 0; i < with.objects.size(); ++i) {
      const Object &a = with.objects[i], &b = without.objects[i];
      ASSERT_EQ(a.id, b.id);
      EXPECT_EQ(a.position, b.position) << "object " << a.id << " t " << t;
      EXPECT_EQ(a.velocity, b.velocity) << "object " << a.id << " t " << t;
      EXPECT_EQ(a.acceleration, b.acceleration) << "object " << a.id << " t " << t;
      EXPECT_EQ(a.heading, b.heading) << "object " << a.id << " t " << t;
      ++objects_seen;
    }
  }
  EXPECT_GT(objects_seen, 100) << "the demo's objects were sampled";
}
