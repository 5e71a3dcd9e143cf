#pragma once
// Scenarios: the ground truth a simulation runs on, read from JSON (nlohmann-json).
//
// File format (degrees and metres in the file, radians inside; every field is required unless
// marked optional; positions are box centres, ISO 8855 axes, map frame with the road at z = 0):
//   {
//     "name": "demo_urban",                          (optional)
//     "duration": 10.0, "rate_hz": 10.0,             seconds, frames per second
//     "sensor": {
//       "mount": {"x":1.0, "y":0, "z":1.73, "roll_deg":0, "pitch_deg":0, "yaw_deg":0},
//       "beams": "hdl64e"  or  {"rows":32, "top_deg":15, "bottom_deg":-25}
//                or {"elevations_deg": [15.0, 13.0, ...]}  (any sensor, one entry per beam),
//       "columns": 1024,                             azimuth bins over 360 deg
//       "fov": {"horizontal_deg":[-180,180], "vertical_deg":[-25,3]},
//       "max_range": 120,  "min_range": 0.5          (min_range optional, default 0)
//     },
//     "ego": {"states": [STATE, ...]},               the ego's ground point (z = road height)
//     "objects": [{"id":1, "class":"Car", "size":[4.5,1.8,1.5], "material":"car_paint",
//                  "states":[STATE, ...]}, ...],   (material optional: from the class)
//     "lanes": [{"id":1, "type":"solid"|"dashed"|"road_edge", "points":[[x,y(,z)], ...]}],
//     "scenery": [{"kind":"box"|"extrusion"|"tree"|"pole", ...}, ...]   (optional: static
//                 buildings, walls, fences, trees, poles and signs, sidewalks; sensor/scenery.h)
//   }
//   STATE = {"t":0.0, "position":[x,y,z], "velocity":[vx,vy,vz], "heading_deg":0,
//            "acceleration":[ax,ay,az]}             (acceleration optional, default 0)
// Every number must be finite (NaN/Infinity, as Python's json writes them, are reported with
// their JSON path); sizes positive; state times strictly increasing; ids unique.
//
// Sampling at time t: between two keyframes the state follows the quintic Hermite curve through
// both keyframes' position, velocity and acceleration (so keyframes taken from a
// constant-acceleration motion are reproduced exactly and the path is C2); heading is
// interpolated linearly along the shorter arc. An object with several keyframes exists only
// within [first t, last t] (that is how objects enter and leave a scene); one with a single
// keyframe exists at all times, extrapolated with constant acceleration and constant heading.
// The ego always exists: outside its keyframes it is extrapolated from the nearest one with
// constant acceleration. Lane polylines are resampled on reading to at most 0.5 m between points
// so occlusion and field of view can drop exactly the hidden part of a marking.
#include <cstddef>
#include <filesystem>
#include <string>
#include <vector>

#include "pgm/beam_layout.h"
#include "sensor/fov.h"
#include "sensor/scene.h"

namespace lidarsim::sensor {

struct BeamSpec {
  std::string kind = "hdl64e";  // "hdl64e", "uniform", "list" or "layout" (a whole layout, e.g. a sensor file)
  int rows = 64;                // uniform only
  double top_deg = 2.0, bottom_deg = -24.9;  // uniform only
  std::vector<double> elevations_deg;        // list only
  pgm::BeamLayout full;                      // layout only (data/sensors/*.json: offsets, ranges)
  int columns = 1024;
  pgm::BeamLayout layout() const;
};

struct SensorSpec {
  Pose mount;  // sensor in ego
  BeamSpec beams;
  FieldOfView fov;
};

struct KinematicState {
  double t = 0;
  Eigen::Vector3d position = Eigen::Vector3d::Zero();
  Eigen::Vector3d velocity = Eigen::Vector3d::Zero();
  Eigen::Vector3d acceleration = Eigen::Vector3d::Zero();
  double heading = 0;  // rad
};

struct ScenarioObject {
  int id = -1;
  ObjectClass cls = ObjectClass::Car;
  std::string material;
  Eigen::Vector3d size = Eigen::Vector3d::Ones();
  std::vector<KinematicState> states;  // strictly increasing t
};

struct Scenario {
  std::string name;
  std::string source;  // file it was read from
  double duration = 10;
  double rate_hz = 10;
  SensorSpec sensor;
  std::vector<KinematicState> ego;
  std::vector<ScenarioObject> objects;
  std::vector<LanePolyline> lanes;  // map frame
  std::vector<SceneryBox> scenery;  // map frame: the "scenery" elements as boxes (sensor/scenery.h)

  int frame_count() const;          // floor(duration * rate + 1e-9)
  double frame_time(int k) const { return k / rate_hz; }
};

// Throws lidarsim::Error "file: json.path: what was expected, got what".
Scenario read_scenario(const std::filesystem::path& path);
// The same from text; `file` names the source in error messages.
Scenario parse_scenario(const std::string& text, const std::string& file);

// Default material of a class when the scenario names none.
std::string default_material(ObjectClass cls);

// State of a keyframe track at t; returns false when the object does not exist at t.
// `interval` (optional) remembers the keyframe interval of the last sample: when t falls in the
// same or the next one it is taken without the binary search (frames sampled in time order), and
// the sample is the same either way.
bool sample_state(const std::vector<KinematicState>& states, double t, KinematicState& out, bool extrapolate,
                  std::size_t* interval = nullptr);

// Where the last samples of a scenario's tracks fell (sample_state's interval per object), for
// sample_frame over frames in time order. Works for any order of t; it only saves searching.
struct SampleCursor {
  std::vector<std::size_t> object_interval;
  std::size_t ego_interval = 0;
};

// The frame at time t in the map frame (ego pose, existing objects, lanes, scenery). `out`'s vectors
// are reused, so a loop over frames does not allocate once they have grown.
void sample_frame(const Scenario& scenario, double t, Frame& out, SampleCursor* cursor = nullptr);

}  // namespace lidarsim::sensor
