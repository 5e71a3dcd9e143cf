#pragma once
// PCL generator: casts the sensor's beam layout (rows x columns, one ray per cell through the
// row's elevation and the column's centre azimuth) against boxes (objects and static scenery), a
// flat ground plane and lane markings, and writes the nearest return per cell into a Polar Grid
// Map.
//
// Works in the EGO frame, where boxes are yaw-only and the road is the plane z = ground_height:
// rays start at the mount position and point along mount.rotation * (sensor direction), so a
// tilted mount is exact. Pass the ego-frame boxes of the objects the sensor model kept (see
// select_visible) and the scenery; lanes are painted on the road (thin strips lane_width wide;
// dashed ones painted dash_length then blank dash_gap along the polyline; road_edge lines are
// kerbs, not paint, and return asphalt). Every return gets range (m, from the sensor), class and
// material (pgm/materials.h ids: road/asphalt, lane_marking/lane_paint, objects by class and
// their material, scenery with its own), mask = 1, object_id (the object's id; -1 for road, lanes
// and scenery) and intensity = 0 (the network predicts it). Effect channels present in the map
// are filled too: elevation, azimuth, height/x/y/z (sensor frame, like pgm::project) and
// incidence, which is estimated from neighbouring cells by pgm::compute_incidence exactly as for
// recorded scans, so simulated and real inputs of the network are computed alike. point_index of
// a cell with a return is the cell's own index (row * cols + col). Rows are parallel (OpenMP); no
// allocation per frame once the internal buffers have grown. Cost: a cell tests only the boxes
// of its column whose slope range holds its ray, nearest first, and stops at the first box whose
// nearest point is beyond its best hit.
#include <cstdint>
#include <memory>
#include <vector>

#include "pgm/beam_layout.h"
#include "pgm/polar_grid_map.h"
#include "sensor/occlusion.h"
#include "sensor/scene.h"

namespace lidarsim::sensor {

struct RangeNoiseModel;
class ReturnModel;  // sensor/return_model.h

struct PclConfig {
  bool ground = true;
  bool lanes = true;
  double ground_height = 0;  // road height in the ego frame, m
  double lane_width = 0.15;  // m
  double dash_length = 3.0, dash_gap = 6.0;  // m
  double min_range = 0;      // returns nearer than this are dropped (the ray is still blocked)
  double max_range = 120;    // m
  // Beams outside the field of view's angular limits return nothing (sensor frame, rad).
  double azimuth_min = -3.14159265358979323846, azimuth_max = 3.14159265358979323846;
  double elevation_min = -3.14159265358979323846 / 2, elevation_max = 3.14159265358979323846 / 2;
  // Range noise (sensor/range_noise.h) applied to every return before the neighbourhood channels
  // are estimated, as a real scan's are from its noisy ranges; null = exact ranges. The draws
  // depend only on (range_noise_seed, the frame set by set_frame, cell).
  std::shared_ptr<const RangeNoiseModel> range_noise;
  std::uint64_t range_noise_seed = 1;
  // Return model (sensor/return_model.h; null = off, every beam that meets geometry returns):
  // each return is kept with the model's probability, drawn from (return_seed, frame, cell).
  std::shared_ptr<const ReturnModel> returns;
  std::uint64_t return_seed = 1;
  // Range and angular limits from a field of view; the rest at their defaults.
  static PclConfig from_fov(const FieldOfView& fov);
};

// Channels a generated map has at least.
inline const std::vector<std::string> kPclChannels = {"range", "class", "material", "intensity", "mask", "object_id"};

class PclGenerator {
 public:
  PclGenerator(pgm::BeamLayout layout, const Pose& mount, const PclConfig& config = {});

  // A map with kPclChannels plus `extra` (e.g. "incidence", "height") for this layout.
  pgm::PolarGridMap make_map(const std::vector<std::string>& extra = {}) const;

  // Fills `out` (made by make_map, or any map of this layout: missing base channels are added).
  // Returns the number of cells with a return. Throws lidarsim::Error for an unknown material.
  // neighbourhood_channels = false leaves "incidence" and "depth_discontinuity" at 0 instead of
  // estimating them from neighbouring cells: they are only the network's inputs, so a frame whose
  // intensity is not predicted need not pay for them (everything else is the same).
  int generate(const std::vector<Object>& objects_ego, const std::vector<LanePolyline>& lanes_ego,
               pgm::PolarGridMap& out, bool neighbourhood_channels = true);
  // The same with static scenery (ego frame, sensor/scenery.h): its boxes block beams like the
  // objects' and return with their own class and material and object_id -1.
  int generate(const std::vector<Object>& objects_ego, const std::vector<SceneryBox>& scenery_ego,
               const std::vector<LanePolyline>& lanes_ego, pgm::PolarGridMap& out, bool neighbourhood_channels = true);

  const pgm::BeamLayout& layout() const { return layout_; }
  const Pose& mount() const { return mount_; }
  const PclConfig& config() const { return cfg_; }
  // Frame index the range noise and return draws of the next generate() are keyed by; each
  // generate() counts on.
  void set_frame(std::uint64_t frame) { frame_ = frame; }

 private:
  struct Box {
    RayBox ray;
    int id, class_id, material_id;
    float near;                // distance from the mount to the box's nearest point (a bit less)
    float slope_lo, slope_hi;  // slopes (dz / horizontal distance) of the rays that can meet it
  };
  struct Segment {
    double ax, ay, bx, by, s0;  // end points and arc length at a
    LaneType type;
  };
  // A box in the cast list, unless it is wholly beyond max_range (id -1 for scenery).
  void add_box(const Eigen::Vector3d& position, const Eigen::Vector3d& size, double heading, int id, int class_id,
               int material_id);
  void prepare_boxes(const std::vector<Object>& objects_ego, const std::vector<SceneryBox>& scenery_ego);
  void prepare_lanes(const std::vector<LanePolyline>& lanes_ego);
  bool painted(double x, double y) const;
  // The nearest surface the ray of `cell` (column c) meets within max_range: a box index, or
  // road / lane paint / nothing (the constants in pcl_generator.cpp).
  struct Hit {
    double range;
    int target;
  };
  Hit cast(std::size_t cell, int c, bool lanes_on) const;

  pgm::BeamLayout layout_;
  Pose mount_;
  Pose sensor_from_ego_;
  PclConfig cfg_;
  std::uint64_t frame_ = 0;
  std::vector<Eigen::Vector3d> dir_sensor_;  // [rows * cols] unit ray directions, sensor frame
  std::vector<Eigen::Vector3d> dir_ego_;     // the same in the ego frame
  std::vector<float> slope_;                 // [rows * cols] dz / horizontal length of dir_ego_
  std::vector<char> cell_in_fov_;            // [rows * cols]
  // Boxes (objects' and scenery's, by increasing `near`) bucketed by column (CSR): column c holds
  // box_index_[col_start_[c] .. col_start_[c+1]), nearest first.
  std::vector<Box> boxes_;
  std::vector<int> col_start_, col_fill_, box_index_;
  std::vector<std::pair<int, int>> box_cols_;  // per box: first column, column count
  // Lane segments bucketed on a square grid over the ego's surroundings (CSR, like the boxes).
  std::vector<Segment> segments_;
  double grid_cell_ = 1.0, grid_origin_ = 0;
  int grid_n_ = 0;
  std::vector<int> cell_start_, cell_fill_, seg_index_;
  std::vector<std::pair<int, int>> seg_cells_lo_, seg_cells_hi_;
};

// The ego-frame objects (from ego_objects) whose id is among `visible` (the sensor-frame list
// after field of view and occlusion) with a visible fraction above zero.
void select_visible(const std::vector<Object>& ego_objects, const std::vector<Object>& visible, std::vector<Object>& out);

}  // namespace lidarsim::sensor
