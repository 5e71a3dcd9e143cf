// Names of the scene enums. Object classes are matched case-insensitively, and the two KITTI
// names that are not ours map onto the nearest class (Person_sitting -> Pedestrian,
// Tram -> Misc) so recorded labels read as they are.
#include "sensor/scene.h"

#include <algorithm>
#include <cctype>

#include "common/error.h"

namespace lidarsim::sensor {

std::string to_string(ObjectClass c) {
  switch (c) {
    case ObjectClass::Car: return "Car";
    case ObjectClass::Truck: return "Truck";
    case ObjectClass::Van: return "Van";
    case ObjectClass::Bus: return "Bus";
    case ObjectClass::Pedestrian: return "Pedestrian";
    case ObjectClass::Cyclist: return "Cyclist";
    case ObjectClass::Motorcycle: return "Motorcycle";
    case ObjectClass::Misc: return "Misc";
  }
  return "Misc";
}

ObjectClass object_class_from_string(const std::string& name) {
  std::string n = name;
  std::transform(n.begin(), n.end(), n.begin(), [](unsigned char ch) { return std::tolower(ch); });
  if (n == "car") return ObjectClass::Car;
  if (n == "truck") return ObjectClass::Truck;
  if (n == "van") return ObjectClass::Van;
  if (n == "bus") return ObjectClass::Bus;
  if (n == "pedestrian" || n == "person_sitting") return ObjectClass::Pedestrian;
  if (n == "cyclist") return ObjectClass::Cyclist;
  if (n == "motorcycle") return ObjectClass::Motorcycle;
  if (n == "misc" || n == "tram") return ObjectClass::Misc;
  throw Error("unknown object class '" + name +
              "' (expected Car, Truck, Van, Bus, Pedestrian, Cyclist, Motorcycle or Misc)");
}

}  // namespace lidarsim::sensor
