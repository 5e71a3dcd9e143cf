#include "sensor/frames.h"

#include <cmath>

namespace lidarsim::sensor {

Eigen::Matrix3d rotation_from_rpy(double roll, double pitch, double yaw) {
  return (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) *
          Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitY()) *
          Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX()))
      .toRotationMatrix();
}

Pose make_pose(const Eigen::Vector3d& translation, double roll, double pitch, double yaw) {
  Pose p;
  p.rotation = rotation_from_rpy(roll, pitch, yaw);
  p.translation = translation;
  return p;
}

Pose compose(const Pose& a, const Pose& b) {
  Pose p;
  p.rotation = a.rotation * b.rotation;
  p.translation = a.rotation * b.translation + a.translation;
  return p;
}

Pose inverse(const Pose& pose) {
  Pose p;
  p.rotation = pose.rotation.transpose();
  p.translation = -(p.rotation * pose.translation);
  return p;
}

void transform_object(const Pose& to_from, const Object& in, Object& out, const HeadingTrig* trig) {
  const HeadingTrig h = trig ? *trig : HeadingTrig::of(in.heading);
  out = in;
  out.position = apply(to_from, in.position);
  out.velocity = to_from.rotation * in.velocity;
  out.acceleration = to_from.rotation * in.acceleration;
  const Eigen::Vector3d forward(h.c, h.s, 0.0);
  const Eigen::Vector3d f = to_from.rotation * forward;
  out.heading = std::atan2(f.y(), f.x());
}

void transform_lane(const Pose& to_from, const LanePolyline& in, LanePolyline& out) {
  out.id = in.id;
  out.type = in.type;
  out.points.resize(in.points.size());
  for (std::size_t i = 0; i < in.points.size(); ++i) out.points[i] = apply(to_from, in.points[i]);
}

void transform_scenery(const Pose& to_from, const SceneryBox& in, SceneryBox& out) {
  out = in;
  out.position = apply(to_from, in.position);
  const Eigen::Vector3d f = to_from.rotation * Eigen::Vector3d(std::cos(in.heading), std::sin(in.heading), 0.0);
  out.heading = std::atan2(f.y(), f.x());
}

void transform_frame(const Pose& to_from, const Frame& in, Frame& out) {
  out.time = in.time;
  out.ego_in_map = in.ego_in_map;
  out.objects.resize(in.objects.size());
  for (std::size_t i = 0; i < in.objects.size(); ++i) transform_object(to_from, in.objects[i], out.objects[i]);
  out.lanes.resize(in.lanes.size());
  for (std::size_t i = 0; i < in.lanes.size(); ++i) transform_lane(to_from, in.lanes[i], out.lanes[i]);
  out.scenery.resize(in.scenery.size());
  for (std::size_t i = 0; i < in.scenery.size(); ++i) transform_scenery(to_from, in.scenery[i], out.scenery[i]);
}

void map_to_ego(const Frame& map_frame, Frame& ego_frame) {
  transform_frame(inverse(map_frame.ego_in_map), map_frame, ego_frame);
}

void ego_to_sensor(const Frame& ego_frame, const Pose& mount, Frame& sensor_frame) {
  transform_frame(inverse(mount), ego_frame, sensor_frame);
}

}  // namespace lidarsim::sensor
