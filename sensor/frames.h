#pragma once
// Coordinate system manager: map -> ego -> sensor. A Pose maps child coordinates into its
// parent (p_parent = R p_child + t): Frame::ego_in_map is the ego in the map, the mount is the
// sensor in the ego. Positions transform as points; velocity and acceleration transform as
// vectors (rotation only), so they stay over-ground quantities expressed in the new axes, which
// is what an object list reports. Heading becomes the yaw of the box's forward axis seen in the
// new frame (exact when the mount has no roll/pitch; with a tilted mount the box keeps z up).
#include <cmath>
#include <numbers>

#include "sensor/scene.h"

namespace lidarsim::sensor {

// Rotation R = Rz(yaw) Ry(pitch) Rx(roll) (intrinsic z-y'-x''), angles in radians.
Eigen::Matrix3d rotation_from_rpy(double roll, double pitch, double yaw);
Pose make_pose(const Eigen::Vector3d& translation, double roll, double pitch, double yaw);
Pose compose(const Pose& parent_from_mid, const Pose& mid_from_child);  // parent_from_child
Pose inverse(const Pose& pose);
// An angle wrapped into [-pi, pi] (remainder by 2 pi; +-pi stay where they are). The remainder is
// exact and leaves |a| <= pi as it is (the quotient rounds to 0, half to even), so only larger
// angles pay for the call.
inline double wrap_pi(double a) {
  return std::abs(a) <= std::numbers::pi ? a : std::remainder(a, 2 * std::numbers::pi);
}

inline Eigen::Vector3d apply(const Pose& pose, const Eigen::Vector3d& p) {
  return pose.rotation * p + pose.translation;
}

// cos and sin of an object's heading. Several stages of a frame need them for the same heading
// (field of view, occlusion, the tracker's frame change): the pipeline computes them once.
struct HeadingTrig {
  double c = 1, s = 0;
  static HeadingTrig of(double heading) { return {std::cos(heading), std::sin(heading)}; }
};

// One object or polyline from the frame F into frame G, given G_from_F. `trig`, when given, is
// HeadingTrig::of(in.heading) (the same numbers, not computed again).
void transform_object(const Pose& to_from, const Object& in, Object& out, const HeadingTrig* trig = nullptr);
void transform_lane(const Pose& to_from, const LanePolyline& in, LanePolyline& out);
void transform_scenery(const Pose& to_from, const SceneryBox& in, SceneryBox& out);

// A whole frame: out gets time and ego pose from in, objects, lanes and scenery in the new frame.
// out's vectors are reused (no allocation once they have grown), and out may not alias in.
void transform_frame(const Pose& to_from, const Frame& in, Frame& out);
// Convenience for the two steps of the chain.
void map_to_ego(const Frame& map_frame, Frame& ego_frame);
void ego_to_sensor(const Frame& ego_frame, const Pose& mount, Frame& sensor_frame);

}  // namespace lidarsim::sensor
