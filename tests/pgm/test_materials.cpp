#include <gtest/gtest.h>

#include <set>

#include "common/error.h"
#include "pgm/materials.h"

using namespace lidarsim::pgm;

TEST(Materials, EveryClassAndMaterialNameRoundTrips) {
  for (int c = 0; c < class_count(); ++c) EXPECT_EQ(class_from_name(class_name(c)), c);
  for (int m = 0; m < material_count(); ++m) EXPECT_EQ(material_from_name(material_name(m)), m);
  EXPECT_THROW(class_from_name("spaceship"), lidarsim::Error);
  EXPECT_THROW(material_from_name("chrome"), lidarsim::Error);
  EXPECT_THROW(class_name(class_count()), lidarsim::Error);
}

TEST(Materials, SemanticKittiLabelsMapToClassesAndMaterials) {
  EXPECT_EQ(class_from_semantickitti(10), cls::car);
  EXPECT_EQ(class_from_semantickitti(252), cls::car);  // moving-car is a car
  EXPECT_EQ(class_from_semantickitti(60), cls::lane_marking);
  EXPECT_EQ(class_from_semantickitti(81), cls::traffic_sign);
  EXPECT_EQ(class_from_semantickitti(1), cls::unlabeled);
  EXPECT_EQ(class_from_semantickitti(12345), cls::unlabeled);
  EXPECT_FALSE(is_known_semantickitti_label(12345));
  EXPECT_EQ(default_material(cls::road), material::asphalt);
  EXPECT_EQ(default_material(cls::lane_marking), material::lane_paint);
  EXPECT_EQ(default_material(cls::car), material::car_paint);
  EXPECT_EQ(default_material(cls::traffic_sign), material::retroreflective_sign);
  EXPECT_EQ(default_material(cls::person), material::skin_fabric);
  EXPECT_EQ(default_material(cls::terrain), material::terrain);
}

TEST(Materials, ObjectTypesMapAndUnknownTypeThrows) {
  EXPECT_EQ(class_from_object_type("Car"), cls::car);
  EXPECT_EQ(class_from_object_type("Van"), cls::car);
  EXPECT_EQ(class_from_object_type("Pedestrian"), cls::person);
  EXPECT_EQ(class_from_object_type("Cyclist"), cls::bicyclist);
  EXPECT_EQ(class_from_object_type("Truck"), cls::truck);
  EXPECT_EQ(class_from_object_type("DontCare"), -1);
  EXPECT_THROW(class_from_object_type("Zeppelin"), lidarsim::Error);
}

TEST(Materials, DefaultClassGroupsCoverEveryClassExactlyOnce) {
  std::multiset<int> seen;
  for (const auto& g : default_class_groups())
    for (int c : g.classes) seen.insert(c);
  for (int c = 0; c < class_count(); ++c) EXPECT_EQ(seen.count(c), 1u) << class_name(c);
}
