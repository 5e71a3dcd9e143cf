#include "sensor/scenario.h"

#include <nlohmann/json.hpp>

#include <cctype>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <numbers>
#include <set>
#include <sstream>

#include "common/angles.h"
#include "common/error.h"
#include "pgm/materials.h"
#include "sensor/frames.h"
#include "sensor/scenario_reader.h"

namespace lidarsim::sensor {

namespace {

using nlohmann::json;
using scenario_json::kNonFinite;
using scenario_json::Reader;
// Limits that keep a scenario within what a simulation can hold (1e8 columns or 10,000 objects
// would end in bad_alloc or minutes of work): beyond them the reader refuses, naming the field.
constexpr std::size_t kMaxObjects = 2000;
constexpr int kMaxFrames = 1000000;
constexpr double kMaxLaneLength = 100000;  // m
// Replaces a NaN/Infinity/overflowing literal by a marked string before parsing, so the reader
// can name the field that held it (standard JSON has no such numbers; Python writes them).

std::string mark_non_finite(const std::string& text) {
  std::string out;
  out.reserve(text.size());
  std::size_t i = 0;
  const auto n = text.size();
  while (i < n) {
    const char c = text[i];
    if (c == '"') {  // copy a string literal verbatim
      std::size_t j = i + 1;
      while (j < n && text[j] != '"') j += (text[j] == '\\') ? 2 : 1;
      out.append(text, i, std::min(j + 1, n) - i);
      i = j + 1;
      continue;
    }
    const bool starts_number = c == '-' || std::isdigit(static_cast<unsigned char>(c));
    const bool starts_word = std::isalpha(static_cast<unsigned char>(c));
    if (starts_number || starts_word) {
      std::size_t j = i + 1;
      while (j < n && (std::isalnum(static_cast<unsigned char>(text[j])) || text[j] == '.' ||
                       text[j] == '+' || text[j] == '-' || text[j] == '_'))
        ++j;
      const std::string token = text.substr(i, j - i);
      bool bad = false;
      if (starts_word) {
        bad = token != "true" && token != "false" && token != "null";
      } else {
        const char* first_alpha = token.c_str() + (token[0] == '-' ? 1 : 0);
        if (std::isalpha(static_cast<unsigned char>(*first_alpha))) {
          bad = true;  // -Infinity, -nan
        } else {
          char* end = nullptr;
          const double v = std::strtod(token.c_str(), &end);
          bad = !std::isfinite(v);
        }
      }
      // Only NaN/Inf-like words are marked; other bare words stay and fail in the parser.
      if (bad) {
        std::string low;
        for (char ch : token) low += static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
        const bool nonfinite_word = low.find("nan") != std::string::npos || low.find("inf") != std::string::npos;
        if (starts_word && !nonfinite_word) bad = false;
      }
      if (bad) out += "\"" + kNonFinite + token + "\"";
      else out += token;
      i = j;
      continue;
    }
    out += c;
    ++i;
  }
  return out;
}


KinematicState read_state(const Reader& r, const json& j, const std::string& path) {
  KinematicState s;
  s.t = r.number(j, path, "t");
  s.position = r.vec(j, path, "position");
  s.velocity = r.vec(j, path, "velocity");
  if (const json* a = r.optional(j, "acceleration")) s.acceleration = r.vec(*a, Reader::join(path, "acceleration"));
  s.heading = r.number(j, path, "heading_deg") * kDeg;
  return s;
}

std::vector<KinematicState> read_states(const Reader& r, const json& obj, const std::string& path) {
  const json& arr = r.array(obj, path, "states", 1);
  const std::string apath = Reader::join(path, "states");
  std::vector<KinematicState> states;
  for (std::size_t i = 0; i < arr.size(); ++i) {
    states.push_back(read_state(r, arr[i], Reader::index(apath, i)));
    if (i > 0 && !(states[i].t > states[i - 1].t))
      r.fail(Reader::index(apath, i) + ".t", "must be greater than the previous state's t (" +
                                                 Reader::fmt(states[i - 1].t) + "), got " + Reader::fmt(states[i].t));
  }
  return states;
}

LaneType lane_type_from(const Reader& r, const std::string& s, const std::string& path) {
  if (s == "solid") return LaneType::Solid;
  if (s == "dashed") return LaneType::Dashed;
  if (s == "road_edge") return LaneType::RoadEdge;
  r.fail(path, "must be \"solid\", \"dashed\" or \"road_edge\", got \"" + s + "\"");
}

// Inserts points so that no two consecutive points are more than `step` apart.
std::vector<Eigen::Vector3d> resample(const std::vector<Eigen::Vector3d>& pts, double step) {
  std::vector<Eigen::Vector3d> out;
  out.push_back(pts.front());
  for (std::size_t i = 1; i < pts.size(); ++i) {
    const Eigen::Vector3d d = pts[i] - pts[i - 1];
    const int n = std::max(1, static_cast<int>(std::ceil(d.norm() / step)));
    for (int k = 1; k <= n; ++k) out.push_back(pts[i - 1] + d * (static_cast<double>(k) / n));
  }
  return out;
}


void extrapolate(const KinematicState& s, double t, KinematicState& out) {
  const double dt = t - s.t;
  out = s;
  out.t = t;
  out.position = s.position + s.velocity * dt + 0.5 * s.acceleration * dt * dt;
  out.velocity = s.velocity + s.acceleration * dt;
}

}  // namespace

pgm::BeamLayout BeamSpec::layout() const {
  if (kind == "hdl64e") return pgm::BeamLayout::hdl64e(columns);
  if (kind == "layout") return full;
  if (kind == "list") return pgm::BeamLayout::from_elevations_deg("list", elevations_deg, columns);
  return pgm::BeamLayout::uniform(rows, top_deg, bottom_deg, columns);
}

int Scenario::frame_count() const { return static_cast<int>(std::floor(duration * rate_hz + 1e-9)); }

std::string default_material(ObjectClass cls) {
  return pgm::material_name(pgm::default_material(pgm::class_from_object_type(to_string(cls))));
}

namespace {

// sensor.beams (a name, an elevation list or a uniform fan) and sensor.columns, into `beams`.
void read_beams(const Reader& r, const json& sj, BeamSpec& beams) {
  const json& bj = r.field(sj, "sensor", "beams");
  if (bj.is_string()) {
    if (bj.get<std::string>() != "hdl64e")
      r.fail("sensor.beams", "must be \"hdl64e\" or {rows, top_deg, bottom_deg}, got " + Reader::describe(bj));
    beams.kind = "hdl64e";
  } else if (bj.is_object() && bj.contains("elevations_deg")) {
    beams.kind = "list";
    const json& ej = r.array(bj, "sensor.beams", "elevations_deg", 1);
    std::set<double> seen;
    for (std::size_t i = 0; i < ej.size(); ++i) {
      const std::string p = Reader::index("sensor.beams.elevations_deg", i);
      const double e = r.number(ej[i], p);
      if (std::abs(e) > 90) r.fail(p, "must lie within [-90, 90] degrees, got " + Reader::fmt(e));
      if (!seen.insert(e).second) r.fail(p, "repeats the elevation " + Reader::fmt(e));
      beams.elevations_deg.push_back(e);
    }
    beams.rows = static_cast<int>(ej.size());
  } else {
    beams.kind = "uniform";
    beams.rows = r.integer(bj, "sensor.beams", "rows", 1);
    beams.top_deg = r.number(bj, "sensor.beams", "top_deg");
    beams.bottom_deg = r.number(bj, "sensor.beams", "bottom_deg");
    if (!(beams.top_deg > beams.bottom_deg) && beams.rows > 1)
      r.fail("sensor.beams.top_deg", "must be above bottom_deg (" + Reader::fmt(beams.bottom_deg) + "), got " +
                                         Reader::fmt(beams.top_deg));
    if (std::abs(beams.top_deg) > 90 || std::abs(beams.bottom_deg) > 90)
      r.fail("sensor.beams", "elevations must lie within [-90, 90] degrees");
  }
  beams.columns = r.integer(sj, "sensor", "columns", 1);
  if (beams.columns > pgm::BeamLayout::kMaxColumns)
    r.fail("sensor.columns", "at most " + std::to_string(pgm::BeamLayout::kMaxColumns) + ", got " +
                                 std::to_string(beams.columns));
  if (beams.rows > pgm::BeamLayout::kMaxRows)
    r.fail("sensor.beams", "at most " + std::to_string(pgm::BeamLayout::kMaxRows) + " rows, got " +
                               std::to_string(beams.rows));
}

// sensor.fov, sensor.max_range and the optional sensor.min_range, into `fov`.
void read_fov(const Reader& r, const json& sj, FieldOfView& fov) {
  const json& fj = r.field(sj, "sensor", "fov");
  const json& hj = r.array(fj, "sensor.fov", "horizontal_deg", 2);
  const json& vj = r.array(fj, "sensor.fov", "vertical_deg", 2);
  fov.azimuth_min = r.number(hj[0], "sensor.fov.horizontal_deg[0]") * kDeg;
  fov.azimuth_max = r.number(hj[1], "sensor.fov.horizontal_deg[1]") * kDeg;
  fov.elevation_min = r.number(vj[0], "sensor.fov.vertical_deg[0]") * kDeg;
  fov.elevation_max = r.number(vj[1], "sensor.fov.vertical_deg[1]") * kDeg;
  if (!(fov.azimuth_max > fov.azimuth_min) || fov.azimuth_max - fov.azimuth_min > 2 * std::numbers::pi + 1e-9)
    r.fail("sensor.fov.horizontal_deg", "must be [min, max] with min < max and at most 360 degrees wide, got " +
                                            Reader::describe(hj));
  if (!(fov.elevation_max > fov.elevation_min) || fov.elevation_min < -std::numbers::pi / 2 - 1e-9 ||
      fov.elevation_max > std::numbers::pi / 2 + 1e-9)
    r.fail("sensor.fov.vertical_deg", "must be [min, max] with -90 <= min < max <= 90, got " + Reader::describe(vj));
  fov.range_max = r.positive(sj, "sensor", "max_range");
  if (const json* mr = r.optional(sj, "min_range")) {
    fov.range_min = r.number(*mr, "sensor.min_range");
    if (fov.range_min < 0 || fov.range_min >= fov.range_max)
      r.fail("sensor.min_range", "must be in [0, max_range), got " + Reader::fmt(fov.range_min));
  }
}

void read_sensor(const Reader& r, const json& root, SensorSpec& sensor) {
  const json& sj = r.field(root, "", "sensor");
  const json& mj = r.field(sj, "sensor", "mount");
  const Eigen::Vector3d mt(r.number(mj, "sensor.mount", "x"), r.number(mj, "sensor.mount", "y"),
                           r.number(mj, "sensor.mount", "z"));
  sensor.mount = make_pose(mt, r.number(mj, "sensor.mount", "roll_deg") * kDeg,
                           r.number(mj, "sensor.mount", "pitch_deg") * kDeg,
                           r.number(mj, "sensor.mount", "yaw_deg") * kDeg);
  read_beams(r, sj, sensor.beams);
  read_fov(r, sj, sensor.fov);
}

// objects[i] (path p): id, class, size, material (the class's default when absent), states.
ScenarioObject read_object(const Reader& r, const json& oj, const std::string& p, std::set<int>& ids) {
  ScenarioObject o;
  o.id = r.integer(oj, p, "id", 0);
  if (!ids.insert(o.id).second) r.fail(p + ".id", "must be unique, got " + std::to_string(o.id) + " twice");
  const std::string cls = r.string(oj, p, "class");
  try {
    o.cls = object_class_from_string(cls);
  } catch (const Error& e) {
    r.fail(p + ".class", e.what());
  }
  const json& size = r.field(oj, p, "size");
  o.size = r.vec(size, p + ".size");
  for (int k = 0; k < 3; ++k)
    if (!(o.size[k] > 0)) r.fail(p + ".size[" + std::to_string(k) + "]", "must be positive, got " + Reader::fmt(o.size[k]));
  if (r.optional(oj, "material")) {
    o.material = r.string(oj, p, "material");
    try {
      pgm::material_from_name(o.material);
    } catch (const Error& e) {
      r.fail(p + ".material", e.what());
    }
  } else {
    o.material = default_material(o.cls);
  }
  o.states = read_states(r, oj, p);
  return o;
}

std::vector<ScenarioObject> read_objects(const Reader& r, const json& root) {
  const json& oj = r.array(root, "", "objects", 0);
  if (oj.size() > kMaxObjects)
    r.fail("objects", "at most " + std::to_string(kMaxObjects) + " objects, got " + std::to_string(oj.size()));
  std::set<int> ids;
  std::vector<ScenarioObject> objects;
  for (std::size_t i = 0; i < oj.size(); ++i) objects.push_back(read_object(r, oj[i], Reader::index("objects", i), ids));
  return objects;
}

// lanes[i]: id, type and points, resampled to at most 0.5 m apart.
std::vector<LanePolyline> read_lanes(const Reader& r, const json& root) {
  const json& lj = r.array(root, "", "lanes", 0);
  std::set<int> lane_ids;
  std::vector<LanePolyline> lanes;
  for (std::size_t i = 0; i < lj.size(); ++i) {
    const std::string p = Reader::index("lanes", i);
    LanePolyline lane;
    lane.id = r.integer(lj[i], p, "id", 0);
    if (!lane_ids.insert(lane.id).second) r.fail(p + ".id", "must be unique, got " + std::to_string(lane.id) + " twice");
    lane.type = lane_type_from(r, r.string(lj[i], p, "type"), p + ".type");
    const json& pts = r.array(lj[i], p, "points", 2);
    std::vector<Eigen::Vector3d> raw;
    double length = 0;
    for (std::size_t k = 0; k < pts.size(); ++k) {
      raw.push_back(r.vec(pts[k], Reader::index(p + ".points", k), 2));
      if (k > 0) length += (raw[k] - raw[k - 1]).norm();
    }
    if (length > kMaxLaneLength)
      r.fail(p + ".points", "the lane is " + Reader::fmt(length) + " m long, at most " + Reader::fmt(kMaxLaneLength) +
                                " m are allowed");
    lane.points = resample(raw, 0.5);
    lanes.push_back(std::move(lane));
  }
  return lanes;
}

}  // namespace

Scenario parse_scenario(const std::string& text, const std::string& file) {
  json root;
  try {
    root = json::parse(mark_non_finite(text), nullptr, true, /*ignore_comments=*/true);
  } catch (const json::exception& e) {
    throw input_error(file, "(json)", std::string("not valid JSON: ") + e.what());
  }
  const Reader r(file);
  Scenario sc;
  sc.source = file;
  if (!root.is_object()) r.fail("", "must be a JSON object, got " + Reader::describe(root));
  if (const json* name = r.optional(root, "name")) {
    if (!name->is_string()) r.fail("name", "must be a string, got " + Reader::describe(*name));
    sc.name = name->get<std::string>();
  }
  sc.duration = r.positive(root, "", "duration");
  sc.rate_hz = r.positive(root, "", "rate_hz");
  if (sc.duration * sc.rate_hz > kMaxFrames)
    r.fail("duration", "duration x rate_hz gives " + Reader::fmt(sc.duration * sc.rate_hz) + " frames, at most " +
                           std::to_string(kMaxFrames) + " are allowed");
  read_sensor(r, root, sc.sensor);
  sc.ego = read_states(r, r.field(root, "", "ego"), "ego");
  sc.objects = read_objects(r, root);
  sc.lanes = read_lanes(r, root);
  sc.scenery = scenario_json::read_scenery(r, root);
  return sc;
}

Scenario read_scenario(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw input_error(path.string(), "(file)", "cannot open the scenario file");
  std::stringstream buf;
  buf << in.rdbuf();
  return parse_scenario(buf.str(), path.string());
}

bool sample_state(const std::vector<KinematicState>& states, double t, KinematicState& out, bool extrapolate_always,
                  std::size_t* interval) {
  if (states.empty()) return false;
  if (states.size() == 1 || t <= states.front().t || t >= states.back().t) {
    const bool single = states.size() == 1;
    if (!single && !extrapolate_always) {
      // Keyframe tracks exist on [first, last]; the ends themselves are exact keyframes.
      if (t < states.front().t - 1e-9 || t > states.back().t + 1e-9) return false;
    }
    const KinematicState& s = (single || t <= states.front().t) ? states.front() : states.back();
    extrapolate(s, t, out);
    return true;
  }
  // Keyframe interval [k, k+1] containing t: the unique k with t_k <= t < t_k+1 (t is strictly
  // inside the track here). The remembered interval or the next one when they hold it, else a
  // binary search (which keeps t_lo <= t < t_hi until hi = lo + 1).
  auto holds = [&](std::size_t k) { return k + 1 < states.size() && states[k].t <= t && t < states[k + 1].t; };
  std::size_t k = 0;
  if (interval && holds(*interval)) {
    k = *interval;
  } else if (interval && holds(*interval + 1)) {
    k = *interval + 1;
  } else {
    std::size_t lo = 0, hi = states.size() - 1;
    while (hi - lo > 1) {
      const std::size_t mid = (lo + hi) / 2;
      (states[mid].t <= t ? lo : hi) = mid;
    }
    k = lo;
  }
  if (interval) *interval = k;
  const KinematicState& a = states[k];
  const KinematicState& b = states[k + 1];
  const double h = b.t - a.t, s = (t - a.t) / h;
  // Quintic Hermite: p(s) = sum c_i s^i matching p, h v, h^2 a at both ends.
  const Eigen::Vector3d dp = b.position - a.position;
  const Eigen::Vector3d hv0 = h * a.velocity, hv1 = h * b.velocity;
  const Eigen::Vector3d ha0 = h * h * a.acceleration, ha1 = h * h * b.acceleration;
  const Eigen::Vector3d c0 = a.position, c1 = hv0, c2 = 0.5 * ha0;
  const Eigen::Vector3d c3 = 10 * dp - 6 * hv0 - 4 * hv1 - 1.5 * ha0 + 0.5 * ha1;
  const Eigen::Vector3d c4 = -15 * dp + 8 * hv0 + 7 * hv1 + 1.5 * ha0 - ha1;
  const Eigen::Vector3d c5 = 6 * dp - 3 * hv0 - 3 * hv1 - 0.5 * ha0 + 0.5 * ha1;
  out.t = t;
  out.position = c0 + s * (c1 + s * (c2 + s * (c3 + s * (c4 + s * c5))));
  out.velocity = (c1 + s * (2 * c2 + s * (3 * c3 + s * (4 * c4 + s * 5 * c5)))) / h;
  out.acceleration = (2 * c2 + s * (6 * c3 + s * (12 * c4 + s * 20 * c5))) / (h * h);
  out.heading = wrap_pi(a.heading + s * wrap_pi(b.heading - a.heading));
  return true;
}

void sample_frame(const Scenario& sc, double t, Frame& out, SampleCursor* cursor) {
  out.time = t;
  if (cursor) cursor->object_interval.resize(sc.objects.size(), 0);
  KinematicState ego;
  sample_state(sc.ego, t, ego, /*extrapolate=*/true, cursor ? &cursor->ego_interval : nullptr);
  out.ego_in_map = make_pose(ego.position, 0, 0, ego.heading);
  std::size_t n = 0;
  KinematicState s;
  for (std::size_t i = 0; i < sc.objects.size(); ++i) {
    const auto& o = sc.objects[i];
    if (!sample_state(o.states, t, s, false, cursor ? &cursor->object_interval[i] : nullptr)) continue;
    if (out.objects.size() <= n) out.objects.emplace_back();
    Object& dst = out.objects[n++];
    dst.id = o.id;
    dst.cls = o.cls;
    dst.material = o.material;
    dst.position = s.position;
    dst.velocity = s.velocity;
    dst.acceleration = s.acceleration;
    dst.size = o.size;
    dst.heading = s.heading;
    dst.visible_fraction = 1;
    dst.score = 1;
  }
  out.objects.resize(n);
  out.lanes.resize(sc.lanes.size());
  for (std::size_t i = 0; i < sc.lanes.size(); ++i) {
    out.lanes[i].id = sc.lanes[i].id;
    out.lanes[i].type = sc.lanes[i].type;
    out.lanes[i].points.assign(sc.lanes[i].points.begin(), sc.lanes[i].points.end());
  }
  out.scenery.assign(sc.scenery.begin(), sc.scenery.end());
}

}  // namespace lidarsim::sensor
