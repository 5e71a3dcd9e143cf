#pragma once
// A moving object as the OSI benchmarks put them in a SensorView's ground truth: a medium car
// (4.5 x 1.8 x 1.5 m) or a pedestrian (0.6 x 0.6 x 1.8 m) on the road, heading along its velocity.
#include <cmath>
#include <cstdint>

#include "osi/osi3_subset.pb.h"

namespace lidarsim::bench {

inline osi3::MovingObject* add_bench_object(osi3::GroundTruth& gt, std::uint64_t id, bool ped, double x, double y,
                                            double vx, double vy) {
  auto* o = gt.add_moving_object();
  o->mutable_id()->set_value(id);
  o->set_type(ped ? osi3::MovingObject::TYPE_PEDESTRIAN : osi3::MovingObject::TYPE_VEHICLE);
  if (!ped) o->mutable_vehicle_classification()->set_type(osi3::MovingObject::VehicleClassification::TYPE_MEDIUM_CAR);
  auto* b = o->mutable_base();
  b->mutable_position()->set_x(x);
  b->mutable_position()->set_y(y);
  b->mutable_position()->set_z(ped ? 0.9 : 0.75);
  b->mutable_dimension()->set_length(ped ? 0.6 : 4.5);
  b->mutable_dimension()->set_width(ped ? 0.6 : 1.8);
  b->mutable_dimension()->set_height(ped ? 1.8 : 1.5);
  b->mutable_orientation()->set_yaw(std::atan2(vy, vx));
  b->mutable_velocity()->set_x(vx);
  b->mutable_velocity()->set_y(vy);
  return o;
}

}  // namespace lidarsim::bench
