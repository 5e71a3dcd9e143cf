#include "osi/scenario_trace.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include "osi/osi3_subset.pb.h"
#include "osi/sensor_data.h"
#include "osi/sensor_view.h"
#include "pgm/materials.h"
#include "sensor/frames.h"

namespace lidarsim::osi {

namespace {

// Roll, pitch, yaw of R = Rz(yaw) Ry(pitch) Rx(roll).
void set_orientation(const Eigen::Matrix3d& r, osi3::Orientation3d& o) {
  o.set_yaw(std::atan2(r(1, 0), r(0, 0)));
  o.set_pitch(std::asin(std::clamp(-r(2, 0), -1.0, 1.0)));
  o.set_roll(std::atan2(r(2, 1), r(2, 2)));
}

osi3::LaneBoundary::Classification::Type lane_type(sensor::LaneType t) {
  using C = osi3::LaneBoundary::Classification;
  switch (t) {
    case sensor::LaneType::Dashed: return C::TYPE_DASHED_LINE;
    case sensor::LaneType::RoadEdge: return C::TYPE_ROAD_EDGE;
    default: return C::TYPE_SOLID_LINE;
  }
}


// The OSI type that osi/sensor_view.cpp reads back as `class_id` (scenery_class_from_osi), or the
// nearest one where OSI has none: a sign plate is a reflective structure (read back as a pole of
// retroreflective sheeting), parking a speed bump (road), terrain and other ground "other" (terrain
// is made of mud, which the reader takes as terrain).
osi3::StationaryObject::Classification::Type stationary_type(int class_id) {
  using C = osi3::StationaryObject::Classification;
  namespace c = pgm::cls;
  switch (class_id) {
    case c::building: return C::TYPE_BUILDING;
    case c::pole:
    case c::trunk: return C::TYPE_POLE;
    case c::traffic_sign: return C::TYPE_REFLECTIVE_STRUCTURE;
    case c::fence: return C::TYPE_BARRIER;
    case c::vegetation: return C::TYPE_VEGETATION;
    case c::sidewalk: return C::TYPE_CURBSTONE;
    case c::road:
    case c::parking: return C::TYPE_SPEED_BUMP;
    case c::other_structure: return C::TYPE_WALL;
    default: return C::TYPE_OTHER;
  }
}

// OSI's material for ours where it has one; otherwise OTHER, which the reader takes as the class's own.
osi3::StationaryObject::Classification::Material stationary_material(int material_id) {
  using C = osi3::StationaryObject::Classification;
  namespace m = pgm::material;
  switch (material_id) {
    case m::concrete: return C::MATERIAL_CONCRETE;
    case m::metal: return C::MATERIAL_METAL;
    case m::glass: return C::MATERIAL_GLAS;
    case m::terrain: return C::MATERIAL_MUD;
    default: return C::MATERIAL_OTHER;
  }
}

void add_stationary_box(const Eigen::Vector3d& centre, const Eigen::Vector3d& size, double heading,
                        osi3::StationaryObject::Classification::Type type,
                        osi3::StationaryObject::Classification::Material material, osi3::GroundTruth& gt) {
  auto* o = gt.add_stationary_object();
  o->mutable_id()->set_value(kSceneryIdBase + static_cast<std::uint64_t>(gt.stationary_object_size() - 1));
  auto* b = o->mutable_base();
  set_vector(centre, *b->mutable_position());
  b->mutable_orientation()->set_roll(0);
  b->mutable_orientation()->set_pitch(0);
  b->mutable_orientation()->set_yaw(heading);
  b->mutable_dimension()->set_length(size.x());
  b->mutable_dimension()->set_width(size.y());
  b->mutable_dimension()->set_height(size.z());
  o->mutable_classification()->set_type(type);
  o->mutable_classification()->set_material(material);
}

// Scenery as stationary objects, one per box, except a tree (a trunk box and its crown's boxes,
// sensor/scenery.h add_scenery_tree), which OSI carries as one TYPE_TREE box: the crown's diameter
// square, from the foot to the crown's top. The reader rebuilds a tree of its own proportions in it.
void add_scenery(const std::vector<sensor::SceneryBox>& boxes, osi3::GroundTruth& gt) {
  for (std::size_t i = 0; i < boxes.size(); ++i) {
    const sensor::SceneryBox& b = boxes[i];
    const bool tree = b.class_id == pgm::cls::trunk && i + 4 < boxes.size() && boxes[i + 2].element == b.element &&
                      boxes[i + 2].class_id == pgm::cls::vegetation;
    if (!tree) {
      add_stationary_box(b.position, b.size, b.heading, stationary_type(b.class_id), stationary_material(b.material_id),
                         gt);
      continue;
    }
    const sensor::SceneryBox& middle = boxes[i + 2];  // side sqrt(pi) / 2 x the diameter, 0.6 x the crown's height
    const double diameter = 2 * middle.size.x() / std::sqrt(std::numbers::pi);
    const double bottom = b.position.z() - 0.5 * b.size.z();
    const double top = middle.position.z() + 0.5 * middle.size.z() + 0.2 * middle.size.z() / 0.6;
    add_stationary_box({b.position.x(), b.position.y(), 0.5 * (bottom + top)}, {diameter, diameter, top - bottom}, 0,
                       osi3::StationaryObject::Classification::TYPE_TREE, osi3::StationaryObject::Classification::MATERIAL_WOOD,
                       gt);
    i += 4;  // the crown's four boxes
  }
}

}  // namespace

void sensor_view_from_scenario(const sensor::Scenario& sc, double t, osi3::SensorView& out) {
  out.Clear();
  sensor::Frame frame;
  sensor::sample_frame(sc, t, frame);
  sensor::KinematicState ego;
  sensor::sample_state(sc.ego, t, ego, /*extrapolate=*/true);

  set_version(*out.mutable_version());
  set_timestamp(t, *out.mutable_timestamp());
  out.mutable_sensor_id()->set_value(kSensorId);
  out.mutable_host_vehicle_id()->set_value(kHostId);
  // Our mount is relative to the road point below the rear axle; OSI's to the axle itself.
  auto* mp = out.mutable_mounting_position();
  set_vector(sc.sensor.mount.translation - kRearAxleHeight * Eigen::Vector3d::UnitZ(), *mp->mutable_position());
  set_orientation(sc.sensor.mount.rotation, *mp->mutable_orientation());

  auto* gt = out.mutable_global_ground_truth();
  set_version(*gt->mutable_version());
  *gt->mutable_timestamp() = out.timestamp();
  gt->mutable_host_vehicle_id()->set_value(kHostId);

  auto* host = gt->add_moving_object();
  host->mutable_id()->set_value(kHostId);
  host->set_type(osi3::MovingObject::TYPE_VEHICLE);
  host->mutable_vehicle_classification()->set_type(osi3::MovingObject::VehicleClassification::TYPE_MEDIUM_CAR);
  const Eigen::Vector3d centre_from_rear(kRearAxleBehindCentre, 0, kHostHeight / 2 - kRearAxleHeight);
  set_vector(-centre_from_rear, *host->mutable_vehicle_attributes()->mutable_bbcenter_to_rear());
  auto* hb = host->mutable_base();
  const Eigen::Vector3d rear_axle = sensor::apply(frame.ego_in_map, Eigen::Vector3d(0, 0, kRearAxleHeight));
  set_vector(rear_axle + frame.ego_in_map.rotation * centre_from_rear, *hb->mutable_position());
  set_orientation(frame.ego_in_map.rotation, *hb->mutable_orientation());
  hb->mutable_dimension()->set_length(kHostLength);
  hb->mutable_dimension()->set_width(kHostWidth);
  hb->mutable_dimension()->set_height(kHostHeight);
  set_vector(ego.velocity, *hb->mutable_velocity());
  set_vector(ego.acceleration, *hb->mutable_acceleration());

  for (const auto& o : frame.objects) {
    auto* m = gt->add_moving_object();
    m->mutable_id()->set_value(static_cast<std::uint64_t>(o.id));
    m->set_type(static_cast<osi3::MovingObject::Type>(osi_type(o.cls)));
    if (m->type() == osi3::MovingObject::TYPE_VEHICLE)
      m->mutable_vehicle_classification()->set_type(
          static_cast<osi3::MovingObject::VehicleClassification::Type>(osi_vehicle_type(o.cls)));
    auto* b = m->mutable_base();
    set_vector(o.position, *b->mutable_position());
    b->mutable_orientation()->set_roll(0);
    b->mutable_orientation()->set_pitch(0);
    b->mutable_orientation()->set_yaw(o.heading);
    b->mutable_dimension()->set_length(o.size.x());
    b->mutable_dimension()->set_width(o.size.y());
    b->mutable_dimension()->set_height(o.size.z());
    set_vector(o.velocity, *b->mutable_velocity());
    set_vector(o.acceleration, *b->mutable_acceleration());
  }

  for (const auto& l : frame.lanes) {
    auto* lb = gt->add_lane_boundary();
    lb->mutable_id()->set_value(kLaneIdBase + static_cast<std::uint64_t>(l.id));
    lb->mutable_classification()->set_type(lane_type(l.type));
    lb->mutable_classification()->set_color(osi3::LaneBoundary::Classification::COLOR_WHITE);
    for (const auto& p : l.points) set_vector(p, *lb->add_boundary_line()->mutable_position());
  }
  add_scenery(frame.scenery, *gt);
}

}  // namespace lidarsim::osi
