// Static scenery through the whole simulation pipeline: it returns points with its own class and
// no object id, it hides a car behind it from the detector, and it is never a reported object.
#include <gtest/gtest.h>

#include <set>
#include <string>

#include "infer/sim_pipeline.h"
#include "pgm/materials.h"
#include "sensor/kpi_model.h"
#include "sensor/scenario.h"
#include "tests/support/shared_data.h"

namespace lidarsim {
namespace {

// The ego stands at the origin. Car 1 is 15 m ahead in plain view; car 2 stands behind a
// 4 m tall building wall (x = 18 .. 19, y = -20 .. -5: the line of sight to it crosses the wall at
// y = -7.4); a tree and a sidewalk slab beside the road.
const char* kStreet = R"({"duration": 0.6, "rate_hz": 10,
  "sensor": {"mount": {"x": 0, "y": 0, "z": 1.73, "roll_deg": 0, "pitch_deg": 0, "yaw_deg": 0},
             "beams": {"rows": 32, "top_deg": 3, "bottom_deg": -25}, "columns": 512,
             "fov": {"horizontal_deg": [-180, 180], "vertical_deg": [-26, 4]}, "max_range": 70, "min_range": 1},
  "ego": {"states": [{"t": 0, "position": [0, 0, 0], "velocity": [0, 0, 0], "heading_deg": 0}]},
  "objects": [
    {"id": 1, "class": "Car", "size": [4.5, 1.8, 1.5],
     "states": [{"t": 0, "position": [15, 0, 0.75], "velocity": [0, 0, 0], "heading_deg": 0}]},
    {"id": 2, "class": "Car", "size": [4.5, 1.8, 1.5],
     "states": [{"t": 0, "position": [25, -10, 0.75], "velocity": [0, 0, 0], "heading_deg": 0}]}],
  "lanes": [],
  "scenery": [
    {"kind": "box", "class": "building", "position": [18.5, -12.5], "size": [1, 15, 4]},
    {"kind": "tree", "position": [12, 6], "trunk_diameter": 0.4, "trunk_height": 1.5, "crown_diameter": 4,
     "crown_height": 4},
    {"kind": "box", "class": "sidewalk", "position": [0, 5], "size": [60, 3, 0.12]}]})";

TEST(SimScenery, WallHidesTheCarBehindItAndScenerysPointsAreNeverReportedObjects) {
  infer::SimOptions options;
  options.intensity = false;
  options.kpi.noise = options.kpi.misses = options.kpi.false_positives = options.kpi.flips = false;
  infer::SimPipeline pipeline(sensor::parse_scenario(kStreet, "street.json"),
                              sensor::load_kpi_model(testing::source_dir() / "data/models/kpi_pointrcnn.json"),
                              nullptr, options);
  infer::SimFrame frame;
  std::set<int> truth;  // over all frames (a track is reported once confirmed)
  for (int k = 0; k < pipeline.frame_count(); ++k) {
    pipeline.run_frame(k, frame);
    for (const auto& r : frame.reported) truth.insert(r.truth_id);
    EXPECT_LE(frame.reported.size(), 1u) << "frame " << k << ": scenery is never a reported object";
    for (const auto& o : frame.sensor.objects) {
      if (o.id == 2) {
        EXPECT_EQ(o.visible_fraction, 0.0) << "frame " << k;
      }
    }
    int building = 0, vegetation = 0, trunk = 0, sidewalk = 0, car1 = 0;
    for (std::size_t i = 0; i < frame.cloud.size(); ++i) {
      const int cls = static_cast<int>(frame.cloud.cls[i]), id = static_cast<int>(frame.cloud.object_id[i]);
      EXPECT_NE(id, 2) << "a point on the hidden car";
      car1 += id == 1;
      if (cls == pgm::cls::building || cls == pgm::cls::vegetation || cls == pgm::cls::trunk ||
          cls == pgm::cls::sidewalk) {
        EXPECT_EQ(id, -1) << "scenery points carry no object id";
      }
      building += cls == pgm::cls::building;
      vegetation += cls == pgm::cls::vegetation;
      trunk += cls == pgm::cls::trunk;
      sidewalk += cls == pgm::cls::sidewalk;
    }
    EXPECT_GT(car1, 50);
    EXPECT_GT(building, 50);
    EXPECT_GT(vegetation, 20);
    EXPECT_GT(trunk, 3);
    EXPECT_GT(sidewalk, 100);
  }
  EXPECT_EQ(truth, (std::set<int>{1})) << "only car 1 is in view";
  EXPECT_EQ(frame.reported.size(), 1u) << "car 1 is reported in the last frame";
}

}  // namespace
}  // namespace lidarsim
