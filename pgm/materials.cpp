#include "pgm/materials.h"

#include <array>
#include <unordered_map>

#include "common/error.h"

namespace lidarsim::pgm {
namespace {

struct ClassInfo {
  const char* name;
  int material;  // default material of the class
};

// Class -> default material, with why.
const std::array<ClassInfo, cls::count> kClasses = {{
    {"unlabeled", material::unknown},
    {"car", material::car_paint},         // painted metal body; windows are a minority of returns
    {"bicycle", material::metal},         // thin frame, no large painted panels
    {"motorcycle", material::car_paint},  // painted tank and fairings
    {"truck", material::car_paint},
    {"other_vehicle", material::car_paint},
    {"person", material::skin_fabric},
    {"bicyclist", material::skin_fabric},  // the rider dominates the returns
    {"motorcyclist", material::skin_fabric},
    {"road", material::asphalt},
    {"parking", material::asphalt},
    {"sidewalk", material::concrete},  // paving slabs and kerbs
    {"other_ground", material::concrete},
    {"building", material::concrete},      // facades: brick, plaster, concrete (glass unknown)
    {"fence", material::metal},            // mostly metal railings along KITTI roads
    {"vegetation", material::vegetation},  // leaves, hedges
    {"trunk", material::vegetation},       // bark: diffuse and dark like foliage, not concrete
    {"terrain", material::terrain},        // grass on soil, gravel
    {"pole", material::metal},             // street-light and sign poles
    {"traffic_sign", material::retroreflective_sign},  // sign faces are retroreflective sheeting
    {"lane_marking", material::lane_paint},  // paint with glass beads: brighter than asphalt
    {"other_structure", material::concrete},  // walls, bridges, tunnels
    {"other_object", material::unknown},      // bins, benches, boxes: no single material
}};

const std::array<const char*, material::count> kMaterials = {
    "unknown", "asphalt",    "lane_paint", "car_paint",   "metal",
    "glass",   "concrete",   "vegetation", "terrain",     "skin_fabric",
    "retroreflective_sign"};
// glass has no SemanticKITTI class of its own (windows belong to cars and buildings); it is here
// for simulated scenes whose objects name it.

std::string names_of(auto const& table, auto name_of) {
  std::string s;
  for (const auto& e : table) s += (s.empty() ? "" : ", ") + std::string(name_of(e));
  return s;
}

}  // namespace

int class_count() { return cls::count; }
int material_count() { return material::count; }

const std::string& class_name(int class_id) {
  static const auto names = [] {
    std::vector<std::string> v;
    for (const auto& c : kClasses) v.emplace_back(c.name);
    return v;
  }();
  if (class_id < 0 || class_id >= cls::count)
    throw Error("class id: " + std::to_string(class_id) + ": not in 0.." + std::to_string(cls::count - 1));
  return names[class_id];
}

const std::string& material_name(int material_id) {
  static const std::vector<std::string> names(kMaterials.begin(), kMaterials.end());
  if (material_id < 0 || material_id >= material::count)
    throw Error("material id: " + std::to_string(material_id) + ": not in 0.." + std::to_string(material::count - 1));
  return names[material_id];
}

int class_from_name(const std::string& name) {
  for (int i = 0; i < cls::count; ++i)
    if (name == kClasses[i].name) return i;
  throw Error("class '" + name + "': unknown; expected one of " +
              names_of(kClasses, [](const ClassInfo& c) { return c.name; }));
}

int material_from_name(const std::string& name) {
  for (int i = 0; i < material::count; ++i)
    if (name == kMaterials[i]) return i;
  throw Error("material '" + name + "': unknown; expected one of " +
              names_of(kMaterials, [](const char* m) { return m; }));
}

int default_material(int class_id) {
  if (class_id < 0 || class_id >= cls::count) return material::unknown;
  return kClasses[class_id].material;
}

namespace {
const std::unordered_map<std::uint32_t, int>& semantickitti_table() {
  static const std::unordered_map<std::uint32_t, int> table = {
      {0, cls::unlabeled},      {1, cls::unlabeled},       {10, cls::car},           {11, cls::bicycle},
      {13, cls::other_vehicle}, {15, cls::motorcycle},     {16, cls::other_vehicle}, {18, cls::truck},
      {20, cls::other_vehicle}, {30, cls::person},         {31, cls::bicyclist},     {32, cls::motorcyclist},
      {40, cls::road},          {44, cls::parking},        {48, cls::sidewalk},      {49, cls::other_ground},
      {50, cls::building},      {51, cls::fence},          {52, cls::other_structure}, {60, cls::lane_marking},
      {70, cls::vegetation},    {71, cls::trunk},          {72, cls::terrain},       {80, cls::pole},
      {81, cls::traffic_sign},  {99, cls::other_object},   {252, cls::car},          {253, cls::bicyclist},
      {254, cls::person},       {255, cls::motorcyclist},  {256, cls::other_vehicle}, {257, cls::other_vehicle},
      {258, cls::truck},        {259, cls::other_vehicle},
  };
  return table;
}
}  // namespace

bool is_known_semantickitti_label(std::uint32_t semantic_label) {
  return semantickitti_table().count(semantic_label) > 0;
}

int class_from_semantickitti(std::uint32_t semantic_label) {
  auto it = semantickitti_table().find(semantic_label);
  return it == semantickitti_table().end() ? cls::unlabeled : it->second;
}

int class_from_object_type(const std::string& type) {
  static const std::unordered_map<std::string, int> table = {
      {"Car", cls::car},         {"Van", cls::car},  // SemanticKITTI counts vans as cars
      {"Truck", cls::truck},     {"Bus", cls::other_vehicle},
      {"Tram", cls::other_vehicle}, {"Misc", cls::other_vehicle},  // KITTI Misc: trailers, segways, ...
      {"Pedestrian", cls::person}, {"Person_sitting", cls::person}, {"Person", cls::person},
      {"Cyclist", cls::bicyclist}, {"Motorcycle", cls::motorcyclist},
  };
  if (type == "DontCare") return -1;
  auto it = table.find(type);
  if (it == table.end())
    throw Error("object type '" + type +
                "': unknown; expected Car, Van, Truck, Bus, Tram, Misc, Pedestrian, Person_sitting, Person, "
                "Cyclist, Motorcycle or DontCare");
  return it->second;
}

const std::vector<ClassGroup>& default_class_groups() {
  static const std::vector<ClassGroup> groups = {
      {"other", {cls::unlabeled, cls::other_object}},
      {"vehicle", {cls::car, cls::truck, cls::other_vehicle}},
      {"two_wheeler", {cls::bicycle, cls::motorcycle}},
      {"person", {cls::person, cls::bicyclist, cls::motorcyclist}},
      {"road", {cls::road, cls::parking}},
      {"lane_marking", {cls::lane_marking}},
      {"sidewalk", {cls::sidewalk, cls::other_ground}},
      {"building", {cls::building, cls::other_structure}},
      {"fence", {cls::fence}},
      {"vegetation", {cls::vegetation}},
      {"trunk", {cls::trunk}},
      {"terrain", {cls::terrain}},
      {"pole", {cls::pole}},
      {"traffic_sign", {cls::traffic_sign}},
  };
  return groups;
}

}  // namespace lidarsim::pgm
