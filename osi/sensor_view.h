#pragma once
// osi3.SensorView (decoded into osi::msg::SensorView, osi/sensor_view_decoder.h) -> the scene our
// sensor model runs on. Nothing here needs Protocol Buffers but the overloads at the end.
//
// Frames. OSI's global frame is our map frame. The host vehicle frame of OSI has its origin at
// the middle of the rear axle (host base.position + R(host orientation) * bbcenter_to_rear), our
// ego frame at the road point below it (the PCL generator's road is the plane z = 0 of the ego
// frame): the two differ by the rear axle's height above the bottom of the host's box,
// h = bbcenter_to_rear.z + height / 2. So ego_in_map = (rear-axle point - h z, host yaw) and the
// mount in our ego frame is the OSI mounting_position raised by h. Host roll and pitch are not
// used (the road is flat in our model). Missing vehicle_attributes count as a rear axle at the
// box centre.
//
// Objects: every moving object except the host, box centre, yaw, velocity and acceleration as
// given; class from type and vehicle_classification.type (class_from_osi), material from the
// class. Lanes: lane_boundary polylines (no_line boundaries skipped), resampled to at most 0.5 m
// between points like scenario lanes, so occlusion drops exactly the hidden part.
#include <cstdint>
#include <string>
#include <unordered_map>
#include <vector>

#include "osi/messages.h"
#include "sensor/scene.h"

namespace osi3 {
class SensorView;
class Timestamp;
}  // namespace osi3

namespace lidarsim::osi {

// OSI ids are uint64; the model's ids are small ints. One map per run keeps both stable.
class IdMap {
 public:
  int to_model(std::uint64_t osi_id);           // assigns the next int on first sight
  bool known(int model_id) const { return model_id >= 0 && model_id < static_cast<int>(to_osi_.size()); }
  std::uint64_t to_osi(int model_id) const { return to_osi_.at(static_cast<std::size_t>(model_id)); }
  std::size_t size() const { return to_osi_.size(); }

 private:
  std::unordered_map<std::uint64_t, int> to_model_;
  std::vector<std::uint64_t> to_osi_;
};

// One physical detector of the SensorView: lidar_sensor_view[i] (OSI: the technology-specific
// views, one per physical detector, each with its own mount and sensor id in its
// view_configuration; its features are given in its own frame). Without any lidar_sensor_view
// the virtual sensor is the one detector.
struct Detector {
  msg::Identifier sensor_id;                // view_configuration.sensor_id, else SensorView.sensor_id
  msg::MountingPosition mounting_position;  // view_configuration.mounting_position, else the virtual mount
  sensor::Pose mount;                        // the same in our ego frame
};

struct SceneFrame {
  double time = 0;                 // s (SensorView timestamp, else the ground truth's)
  sensor::Frame map;               // map frame: ego pose, objects (host excluded), lanes, scenery
  sensor::Pose mount;              // sensor in our ego frame
  Eigen::Vector3d host_velocity = Eigen::Vector3d::Zero();      // map frame
  Eigen::Vector3d host_acceleration = Eigen::Vector3d::Zero();  // map frame
  std::uint64_t host_id = 0;
  msg::Identifier sensor_id;
  msg::Timestamp timestamp;
  msg::MountingPosition mounting_position;  // as given (host vehicle frame; see sensor_mount)
  std::vector<Detector> detectors;           // one per lidar_sensor_view, at least one
};

// The sensor's mount (host vehicle frame). OSI gives two: SensorView.mounting_position, the
// virtual sensor's (it governs the coordinates of detected objects), and each
// lidar_sensor_view[].view_configuration.mounting_position, a physical detector's (it governs the
// detections of that detector). Our model has one frame for both, so the virtual mount wins when
// present; without it, the first lidar_sensor_view whose view_configuration has a mount is used.
// `field` names where it came from (for errors); null when neither is given.
const msg::MountingPosition* sensor_mount(const msg::SensorView& view, std::string& field);

// Fills `out` from `view`. Errors (lidarsim::Error) read "<source>: message <index>: <field>: <what>":
// no global_ground_truth, no host id, a host id not among the moving objects, no mount
// (sensor_mount), a moving object without id or base position, a stationary object without base
// position or with a dimension that is not positive, more stationary objects than
// sensor::kMaxSceneryElements or scenery boxes than sensor::kMaxSceneryBoxes, non-finite numbers.
// Object and lane ids go through `ids` (object ids and lane ids share it).
void scene_from_sensor_view(const msg::SensorView& view, long index, const std::string& source, IdMap& ids,
                            SceneFrame& out);

// Our class for an OSI moving object: pedestrians; vehicles by vehicle_classification.type
// (vans, trucks and (semi)trailers, buses, trams and trains as buses, motorbikes, bicycles as
// cyclists, cars and unknown vehicle types as cars); animals and others as Misc.
sensor::ObjectClass class_from_osi(const msg::MovingObject& o);
// The OSI type and vehicle type we report for one of our classes.
msg::MovingObjectType osi_type(sensor::ObjectClass c);
msg::VehicleType osi_vehicle_type(sensor::ObjectClass c);

// Our class for an OSI stationary object (global_ground_truth.stationary_object, read as static
// scenery): buildings; poles, delineators, vertical, reflective and emitting structures (street
// lights) as poles; trees as a trunk under a crown of vegetation; barriers as fences; vegetation;
// curbstones as sidewalk (SemanticKITTI labels kerbs so); speed bumps as road; bridges, walls,
// rectangular and overhead structures as other_structure; other and unknown of mud as terrain (a
// patch of soil, as osi/scenario_trace.cpp writes terrain); the rest (pylons, construction site
// elements, other, unknown) as other_object. The material: concrete and stone as concrete,
// metal, glass, mud as terrain, reflective structures retroreflective; else the class's own.
int scenery_class_from_osi(const msg::StationaryObject& o);
int scenery_material_from_osi(const msg::StationaryObject& o, int class_id);

double seconds(const msg::Timestamp& t);
// A pose from an OSI position + orientation (p_parent = R p_child + t, R = Rz(yaw) Ry(pitch) Rx(roll)).
sensor::Pose pose_from_osi(const msg::Vector3d& position, const msg::Orientation3d& orientation);

// With libprotobuf (osi/sensor_view_proto.cpp; tests, tools and `lidar-infer osi --format txth`,
// not the FMU): the same from an osi3.SensorView message (its bytes decoded as above), seconds
// into an osi3.Timestamp.
void scene_from_sensor_view(const osi3::SensorView& view, long index, const std::string& source, IdMap& ids,
                            SceneFrame& out);
msg::SensorView decoded(const osi3::SensorView& view);
void set_timestamp(double seconds, osi3::Timestamp& t);

}  // namespace lidarsim::osi
