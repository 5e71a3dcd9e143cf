#include "sensor/scenery.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <string>

#include "common/angles.h"
#include "common/error.h"
#include "pgm/materials.h"
#include "sensor/scenario_reader.h"

namespace lidarsim::sensor {

namespace {
constexpr double kSignThickness = 0.04;  // m
constexpr double kMaxExtrusionLength = 100000;  // m, as a lane's
}  // namespace

bool is_scenery_class(int c) {
  switch (c) {
    case pgm::cls::road: case pgm::cls::parking: case pgm::cls::sidewalk: case pgm::cls::other_ground:
    case pgm::cls::building: case pgm::cls::fence: case pgm::cls::vegetation: case pgm::cls::trunk:
    case pgm::cls::terrain: case pgm::cls::pole: case pgm::cls::traffic_sign: case pgm::cls::other_structure:
    case pgm::cls::other_object:
      return true;
    default:
      return false;
  }
}

void add_scenery_box(std::vector<SceneryBox>& out, const Eigen::Vector3d& foot, const Eigen::Vector3d& size,
                     double heading, int class_id, int material_id, int element) {
  SceneryBox b;
  b.position = foot + Eigen::Vector3d(0, 0, 0.5 * size.z());
  b.size = size;
  b.heading = heading;
  b.class_id = class_id;
  b.material_id = material_id;
  b.element = element;
  out.push_back(b);
}

void add_scenery_extrusion(std::vector<SceneryBox>& out, const std::vector<Eigen::Vector2d>& points, bool closed,
                           double width, double height, double base, int class_id, int material_id, int element) {
  const std::size_t n = points.size();
  const std::size_t segments = closed ? n : n - 1;
  for (std::size_t i = 0; i < segments; ++i) {
    const Eigen::Vector2d a = points[i], b = points[(i + 1) % n];
    const Eigen::Vector2d mid = 0.5 * (a + b), d = b - a;
    add_scenery_box(out, Eigen::Vector3d(mid.x(), mid.y(), base), Eigen::Vector3d(d.norm() + width, width, height),
                    std::atan2(d.y(), d.x()), class_id, material_id, element);
  }
}

void add_scenery_tree(std::vector<SceneryBox>& out, const Eigen::Vector3d& foot, const TreeShape& t, int element) {
  const int trunk = pgm::cls::trunk, leaves = pgm::cls::vegetation;
  add_scenery_box(out, foot, Eigen::Vector3d(t.trunk_diameter, t.trunk_diameter, t.trunk_height), 0, trunk,
                  pgm::default_material(trunk), element);
  // A square of the crown's area (side sqrt(pi) / 2 x diameter), twice, crossed at 45 degrees:
  // a silhouette within 0.45-0.63 x the diameter of the axis from any side. Caps of 0.6 x that
  // width, as a sphere is at 0.8 of its radius above and below its centre.
  const double side = 0.5 * std::sqrt(std::numbers::pi) * t.crown_diameter, h = t.crown_height;
  const double z0 = foot.z() + t.trunk_height;
  const int mat = pgm::default_material(leaves);
  auto at = [&](double dz) { return Eigen::Vector3d(foot.x(), foot.y(), z0 + dz); };
  add_scenery_box(out, at(0), Eigen::Vector3d(0.6 * side, 0.6 * side, 0.2 * h), std::numbers::pi / 8, leaves, mat,
                  element);
  add_scenery_box(out, at(0.2 * h), Eigen::Vector3d(side, side, 0.6 * h), 0, leaves, mat, element);
  add_scenery_box(out, at(0.2 * h), Eigen::Vector3d(side, side, 0.6 * h), std::numbers::pi / 4, leaves, mat, element);
  add_scenery_box(out, at(0.8 * h), Eigen::Vector3d(0.6 * side, 0.6 * side, 0.2 * h), std::numbers::pi / 8, leaves,
                  mat, element);
}

void add_scenery_pole(std::vector<SceneryBox>& out, const Eigen::Vector3d& foot, double height, double diameter,
                      const std::optional<SignPlate>& sign, int element) {
  add_scenery_box(out, foot, Eigen::Vector3d(diameter, diameter, height), 0, pgm::cls::pole,
                  pgm::default_material(pgm::cls::pole), element);
  if (!sign) return;
  const double off = 0.5 * (diameter + kSignThickness);
  const Eigen::Vector3d face(std::cos(sign->heading), std::sin(sign->heading), 0);
  add_scenery_box(out, foot + off * face + Eigen::Vector3d(0, 0, height - sign->height),
                  Eigen::Vector3d(kSignThickness, sign->width, sign->height), sign->heading, pgm::cls::traffic_sign,
                  pgm::default_material(pgm::cls::traffic_sign), element);
}

double nearest_distance(const SceneryBox& b) {
  const double c = std::cos(b.heading), s = std::sin(b.heading);
  const Eigen::Vector3d r = -b.position;  // the origin relative to the centre, then in box axes
  const double local[3] = {c * r.x() + s * r.y(), -s * r.x() + c * r.y(), r.z()};
  double d2 = 0;
  for (int i = 0; i < 3; ++i) {
    const double out = std::max(0.0, std::abs(local[i]) - 0.5 * b.size[i]);
    d2 += out * out;
  }
  return std::sqrt(d2);
}

void cull_scenery(std::vector<SceneryBox>& boxes, double range) {
  std::erase_if(boxes, [&](const SceneryBox& b) { return nearest_distance(b) > range; });
}

namespace scenario_json {

namespace {

// class (a static one) and material (optional: the class's default) of a box or extrusion.
void read_labels(const Reader& r, const json& e, const std::string& p, int& class_id, int& material_id) {
  const std::string name = r.string(e, p, "class");
  try {
    class_id = pgm::class_from_name(name);
  } catch (const Error& err) {
    r.fail(p + ".class", err.what());
  }
  if (!is_scenery_class(class_id))
    r.fail(p + ".class", "'" + name + "' is not a class of static scenery (vehicles and persons are objects: a parked "
                         "car is an object with one state; lane markings are lanes)");
  material_id = pgm::default_material(class_id);
  if (r.optional(e, "material")) {
    try {
      material_id = pgm::material_from_name(r.string(e, p, "material"));
    } catch (const Error& err) {
      r.fail(p + ".material", err.what());
    }
  }
}

double optional_number(const Reader& r, const json& e, const std::string& p, const char* key, double fallback) {
  return r.optional(e, key) ? r.number(e, p, key) : fallback;
}

Eigen::Vector3d read_size(const Reader& r, const json& e, const std::string& p) {
  const Eigen::Vector3d size = r.vec(e, p, "size");
  for (int k = 0; k < 3; ++k)
    if (!(size[k] > 0)) r.fail(p + ".size[" + std::to_string(k) + "]", "must be positive, got " + Reader::fmt(size[k]));
  return size;
}

void read_extrusion(const Reader& r, const json& e, const std::string& p, int element, std::vector<SceneryBox>& out) {
  int class_id = 0, material_id = 0;
  read_labels(r, e, p, class_id, material_id);
  const bool closed = r.optional(e, "closed") && r.boolean(e, p, "closed");
  const json& pts = r.array(e, p, "points", closed ? 3 : 2);
  if (pts.size() > static_cast<std::size_t>(kMaxSceneryBoxes))
    r.fail(p + ".points", "at most " + std::to_string(kMaxSceneryBoxes) + " points, got " + std::to_string(pts.size()));
  std::vector<Eigen::Vector2d> points;
  double length = 0;
  for (std::size_t k = 0; k < pts.size(); ++k) {
    const std::string pk = Reader::index(p + ".points", k);
    if (!pts[k].is_array() || pts[k].size() != 2) r.fail(pk, "must be an array of 2 numbers, got " + Reader::describe(pts[k]));
    points.emplace_back(r.number(pts[k][0], Reader::index(pk, 0)), r.number(pts[k][1], Reader::index(pk, 1)));
    if (k > 0) {
      const double step = (points[k] - points[k - 1]).norm();
      if (!(step > 1e-6)) r.fail(pk, "repeats the previous point (each segment needs a length)");
      length += step;
    }
  }
  if (closed && !((points.back() - points.front()).norm() > 1e-6))
    r.fail(Reader::index(p + ".points", pts.size() - 1), "repeats the first point (closed joins them already)");
  if (length > kMaxExtrusionLength)
    r.fail(p + ".points", "the polyline is " + Reader::fmt(length) + " m long, at most " +
                              Reader::fmt(kMaxExtrusionLength) + " m are allowed");
  const double width = r.positive(e, p, "width"), height = r.positive(e, p, "height");
  const double base = optional_number(r, e, p, "base", 0);
  add_scenery_extrusion(out, points, closed, width, height, base, class_id, material_id, element);
}

void read_pole(const Reader& r, const json& e, const std::string& p, int element, std::vector<SceneryBox>& out) {
  const Eigen::Vector3d foot = r.vec(r.field(e, p, "position"), p + ".position", 2);
  const double height = r.positive(e, p, "height"), diameter = r.positive(e, p, "diameter");
  std::optional<SignPlate> sign;
  if (const json* sj = r.optional(e, "sign")) {
    const std::string sp = p + ".sign";
    const json& size = r.array(*sj, sp, "size", 2);
    if (size.size() != 2) r.fail(sp + ".size", "must be [width, height], got " + Reader::describe(size));
    sign = SignPlate{r.number(size[0], sp + ".size[0]"), r.number(size[1], sp + ".size[1]"),
                     r.number(*sj, sp, "heading_deg") * kDeg};
    if (!(sign->width > 0)) r.fail(sp + ".size[0]", "must be positive, got " + Reader::fmt(sign->width));
    if (!(sign->height > 0 && sign->height < height))
      r.fail(sp + ".size[1]", "must be positive and below the pole's height (" + Reader::fmt(height) + "), got " +
                                  Reader::fmt(sign->height));
  }
  add_scenery_pole(out, foot, height, diameter, sign, element);
}

void read_element(const Reader& r, const json& e, const std::string& p, int element, std::vector<SceneryBox>& out) {
  const std::string kind = r.string(e, p, "kind");
  if (kind == "box") {
    int class_id = 0, material_id = 0;
    read_labels(r, e, p, class_id, material_id);
    const Eigen::Vector3d foot = r.vec(r.field(e, p, "position"), p + ".position", 2);
    const Eigen::Vector3d size = read_size(r, e, p);
    add_scenery_box(out, foot, size, optional_number(r, e, p, "heading_deg", 0) * kDeg, class_id, material_id, element);
  } else if (kind == "extrusion") {
    read_extrusion(r, e, p, element, out);
  } else if (kind == "tree") {
    const Eigen::Vector3d foot = r.vec(r.field(e, p, "position"), p + ".position", 2);
    TreeShape t;
    t.trunk_diameter = r.positive(e, p, "trunk_diameter");
    t.trunk_height = r.positive(e, p, "trunk_height");
    t.crown_diameter = r.positive(e, p, "crown_diameter");
    t.crown_height = r.positive(e, p, "crown_height");
    add_scenery_tree(out, foot, t, element);
  } else if (kind == "pole") {
    read_pole(r, e, p, element, out);
  } else {
    r.fail(p + ".kind", "must be \"box\", \"extrusion\", \"tree\" or \"pole\", got \"" + kind + "\"");
  }
}

}  // namespace

std::vector<SceneryBox> read_scenery(const Reader& r, const json& root) {
  std::vector<SceneryBox> out;
  if (!r.optional(root, "scenery")) return out;
  const json& sj = r.array(root, "", "scenery", 0);
  if (sj.size() > static_cast<std::size_t>(kMaxSceneryElements))
    r.fail("scenery", "at most " + std::to_string(kMaxSceneryElements) + " elements, got " + std::to_string(sj.size()));
  for (std::size_t i = 0; i < sj.size(); ++i) {
    const std::string p = Reader::index("scenery", i);
    read_element(r, sj[i], p, static_cast<int>(i), out);
    if (out.size() > static_cast<std::size_t>(kMaxSceneryBoxes))
      r.fail(p, "the scenery has more than " + std::to_string(kMaxSceneryBoxes) + " boxes with this element");
  }
  return out;
}

}  // namespace scenario_json

}  // namespace lidarsim::sensor
