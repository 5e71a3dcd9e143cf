#pragma once
// Field of view: range and horizontal/vertical angular limits in the sensor frame. An object is
// visible when any part of its box is inside: its closest point is within range, and the
// angular interval spanned by its 8 corners, centre and closest point overlaps both limits.
// (Interval overlap is slightly generous for a box that only grazes a corner of the FoV
// rectangle; it never drops a box that has a sample point inside.)
#include <cmath>
#include <numbers>
#include <vector>

#include "sensor/frames.h"
#include "sensor/scene.h"

namespace lidarsim::sensor {

struct FieldOfView {
  double azimuth_min = -std::numbers::pi;        // rad, azimuth = atan2(y, x), left positive
  double azimuth_max = std::numbers::pi;
  double elevation_min = -std::numbers::pi / 2;  // rad, elevation = atan2(z, hypot(x, y))
  double elevation_max = std::numbers::pi / 2;
  double range_min = 0;                          // m
  double range_max = 120;                        // m
};

// The 8 corners of an object's box (yaw-only boxes; heading about the frame's z axis).
void box_corners(const Object& o, Eigen::Vector3d corners[8]);
// The point of the box nearest to p (p itself when inside).
Eigen::Vector3d closest_point_on_box(const Object& o, const Eigen::Vector3d& p);

bool point_in_fov(const Eigen::Vector3d& p, const FieldOfView& fov);
bool object_in_fov(const Object& o, const FieldOfView& fov);  // o in the sensor frame

// Share of the object outside the field of view, 0..1: KITTI's "truncated" (the part of the
// box's projection outside the image) in angle space. The box's angular extent is the
// (azimuth, elevation) rectangle spanned by its 8 corners (as KITTI's image box spans its
// projected corners); truncation = 1 - (area of that rectangle inside the FoV's angular
// rectangle) / (its area). Range limits do not truncate. A box around the sensor's vertical
// axis spans every azimuth and reaches straight down (up) when it extends below (above) it.
double fov_truncation(const Object& o, const FieldOfView& fov);  // o in the sensor frame

// Keeps (in order) the objects that are in view and sets their truncation; returns how many
// were removed. `trig`, when given, receives HeadingTrig::of(heading) of each kept object (same
// order), which the later stages of the frame take instead of computing it again.
int apply_fov(std::vector<Object>& objects, const FieldOfView& fov, std::vector<HeadingTrig>* trig = nullptr);
// Drops lane points outside the view; lanes left with fewer than 2 points are removed.
void apply_fov_to_lanes(std::vector<LanePolyline>& lanes, const FieldOfView& fov);

}  // namespace lidarsim::sensor
