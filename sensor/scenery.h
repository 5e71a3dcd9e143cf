#pragma once
// Static scenery: the street around the road users (buildings, walls, fences, hedges, trees,
// poles and signs, sidewalks with their kerbs, terrain). Every element becomes one or more
// yaw-only boxes (SceneryBox, sensor/scene.h) with a PGM class and material, so the occlusion
// stage and the PCL generator treat it like an object's box, but it is never an object: it is not
// tracked, not reported, and its returns carry object_id -1 like the road's.
//
// Scenario format (sensor/scenario.h), an optional top-level array; metres and degrees; z = 0 is
// the road; `position` is the centre of an element's foot ([x, y] on the road or [x, y, z]):
//   "scenery": [
//     {"kind": "box", "class": "building", "material": "concrete",
//      "position": [x, y(, z)], "size": [length, width, height], "heading_deg": 0},
//     {"kind": "extrusion", "class": "fence", "points": [[x, y], ...], "width": 0.1, "height": 1.2,
//      "base": 0, "closed": false},
//     {"kind": "tree", "position": [x, y(, z)], "trunk_diameter": 0.4, "trunk_height": 2.5,
//      "crown_diameter": 4.0, "crown_height": 4.0},
//     {"kind": "pole", "position": [x, y(, z)], "height": 6.0, "diameter": 0.15,
//      "sign": {"size": [width, height], "heading_deg": 180}}
//   ]
// box: any static class (below); material optional (the class's default, pgm/materials.h);
//   heading_deg optional (0). A building, a kiosk, a hedge, a sidewalk slab (its road-side face is
//   the kerb: SemanticKITTI labels kerbs sidewalk), a terrain patch.
// extrusion: a wall along a polyline (at least 2 points; closed: the last joins the first, at least
//   3 points): one box per segment, `width` thick and `height` tall standing on `base` (optional,
//   0), each reaching width / 2 past its ends so that corners close. Building outlines, walls,
//   fences, hedges, long sidewalks.
// tree: a trunk (class trunk) up to trunk_height, under a crown (class vegetation) crown_height
//   tall: a middle part of 0.6 x the crown's height as two squares of the crown's area crossed at
//   45 degrees, and a cap of 0.6 x that width below and above.
// pole: class pole, metal, square of `diameter`; `sign` (optional): a plate (traffic_sign,
//   retroreflective sheeting, 4 cm thick) whose top is the pole's top, on the side it faces
//   (heading_deg: the direction the sign's face looks to).
// Static classes: road, parking, sidewalk, other_ground, building, fence, vegetation, trunk,
// terrain, pole, traffic_sign, other_structure, other_object. Vehicles and persons are objects
// (a parked car is an object with one state: a detector must find it); lane markings are lanes.
#include <optional>
#include <vector>

#include "sensor/scene.h"

namespace lidarsim::sensor {

// Limits the reader enforces (naming the field): beyond them a scenario is not a street.
inline constexpr int kMaxSceneryElements = 20000;
inline constexpr int kMaxSceneryBoxes = 50000;

// True for the classes scenery may have (the list above).
bool is_scenery_class(int class_id);

// The boxes of each kind of element, appended to `out` with `element` as their element index.
// `foot` is the centre of the element's foot (z = its base).
void add_scenery_box(std::vector<SceneryBox>& out, const Eigen::Vector3d& foot, const Eigen::Vector3d& size,
                     double heading, int class_id, int material_id, int element);
void add_scenery_extrusion(std::vector<SceneryBox>& out, const std::vector<Eigen::Vector2d>& points, bool closed,
                           double width, double height, double base, int class_id, int material_id, int element);
struct TreeShape {
  double trunk_diameter = 0.4, trunk_height = 2.5, crown_diameter = 4, crown_height = 4;
};
void add_scenery_tree(std::vector<SceneryBox>& out, const Eigen::Vector3d& foot, const TreeShape& tree, int element);
struct SignPlate {
  double width = 0.6, height = 0.6;
  double heading = 0;  // rad: the direction the face looks to
};
void add_scenery_pole(std::vector<SceneryBox>& out, const Eigen::Vector3d& foot, double height, double diameter,
                      const std::optional<SignPlate>& sign, int element);

// Distance from the origin of the list's frame to the nearest point of the box.
double nearest_distance(const SceneryBox& box);
// Removes the boxes wholly beyond `range` of the origin (the sensor, in a sensor-frame list): they
// can neither block a beam nor return a point. Keeps the order of the others.
void cull_scenery(std::vector<SceneryBox>& boxes, double range);

}  // namespace lidarsim::sensor
