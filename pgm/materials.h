#pragma once
// The one place where classes and materials are defined: the class ids the network sees (the
// `class` channel of a Polar Grid Map), the material ids (the `material` channel), and how
// recorded labels (SemanticKITTI), annotated objects (KITTI / scenario types) map onto them.
//
// Classes follow SemanticKITTI's semantic classes with moving-* merged into their static class,
// but keep lane markings, other-structure and other-object apart (they reflect differently from
// what SemanticKITTI's 19-class training map merges them into). Ids are stable: they are stored
// in datasets and checkpoints; append new ones at the end.
#include <cstdint>
#include <string>
#include <vector>

namespace lidarsim::pgm {

namespace cls {
enum : int {
  unlabeled = 0,  // no label, outliers, and background in KITTI object (points outside boxes)
  car,
  bicycle,
  motorcycle,
  truck,
  other_vehicle,  // bus, tram/on-rails, trailers, other vehicles
  person,
  bicyclist,
  motorcyclist,
  road,
  parking,
  sidewalk,
  other_ground,
  building,
  fence,
  vegetation,
  trunk,
  terrain,
  pole,
  traffic_sign,
  lane_marking,
  other_structure,
  other_object,
  count
};
}  // namespace cls

namespace material {
enum : int {
  unknown = 0,
  asphalt,
  lane_paint,
  car_paint,
  metal,
  glass,
  concrete,  // also brick, plaster: building facades, kerbs, sidewalks
  vegetation,
  terrain,  // soil, gravel, grass-on-soil
  skin_fabric,
  retroreflective_sign,
  count
};
}  // namespace material

int class_count();
int material_count();
const std::string& class_name(int class_id);        // throws lidarsim::Error for an unknown id
const std::string& material_name(int material_id);  // throws lidarsim::Error for an unknown id
int class_from_name(const std::string& name);       // "car", ...; throws naming the valid names
int material_from_name(const std::string& name);    // "car_paint", ...; throws likewise

// The material a class is made of when nothing more specific is known (one table, with the
// reason for each entry in materials.cpp).
int default_material(int class_id);

// SemanticKITTI semantic label (lower 16 bits of a .label entry) -> class id. Labels outside the
// SemanticKITTI definition map to unlabeled (the importer counts them).
int class_from_semantickitti(std::uint32_t semantic_label);
bool is_known_semantickitti_label(std::uint32_t semantic_label);

// KITTI object / tracking types and scenario object classes ("Car", "Van", "Truck", "Bus",
// "Pedestrian", "Person_sitting", "Cyclist", "Motorcycle", "Tram", "Misc") -> class id;
// -1 for "DontCare"; throws lidarsim::Error for anything else.
int class_from_object_type(const std::string& type);

// Groups of classes for the one-hot "class" input of the network (pgm/encoder.h): each group is
// one input channel. The default merges classes that look alike to a LiDAR and are rare alone.
struct ClassGroup {
  std::string name;
  std::vector<int> classes;
};
const std::vector<ClassGroup>& default_class_groups();

}  // namespace lidarsim::pgm
