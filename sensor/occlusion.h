#pragma once
// Occlusion in the sensor's angular (canonical) grid with a depth test.
//
// The grid is uniform in azimuth (full circle) and elevation (the field of view's vertical
// limits), 0.25 deg by default. Each box is rasterised exactly: the ray through a cell centre is
// cast against the box (slab test); a hit makes the cell part of the box's footprint and enters
// the per-cell nearest-depth test. Visible fraction = cells the box wins / cells of its
// footprint. A box too small to cover any cell centre is judged by the cell of its centre
// direction (fraction 0 or 1). Lane points whose cell holds a box nearer than the point are
// dropped.
// Cost: boxes are yaw-only prisms, so the slab test splits into a horizontal part done once per
// column (the footprint rectangle's distance interval along that azimuth) and a height part done
// once per row; a cell costs two products and the depth test (16 cells per AVX-512 step, float),
// and only the columns whose azimuth meets the footprint and the rows between its lowest and
// highest elevation are visited. Boxes are drawn nearest first and wins are counted as they
// happen (a cell taken from a farther box is given back), so nothing walks the grid afterwards
// and the next frame clears only the runs of cells that were written. tests/sensor/occlusion_reference.h keeps a per-cell 3-D
// raster as the reference; tests/sensor/test_occlusion_reference.cpp holds them equal.
#include <utility>
#include <vector>

#include "sensor/fov.h"
#include "sensor/scene.h"

namespace lidarsim::sensor {

// An oriented (yaw-only) box prepared for ray casting.
struct RayBox {
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  Eigen::Vector3d half = Eigen::Vector3d::Ones();
  double cos_h = 1, sin_h = 0;
  static RayBox of(const Object& o);
};

// Ray o + t d (d need not be unit; t in units of |d|) against the box: true and the entry
// distance t_hit (0 when o is inside) when it hits with t_hit <= t_max. normal_axis (0, 1, 2 =
// box x, y, z) and normal_sign tell the face that was entered, in box coordinates.
bool ray_box(const RayBox& b, const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_max, double& t_hit,
             int* normal_axis = nullptr, int* normal_sign = nullptr);

struct OcclusionConfig {
  double azimuth_resolution = 0.25 * 3.14159265358979323846 / 180;    // rad
  double elevation_resolution = 0.25 * 3.14159265358979323846 / 180;  // rad
  double elevation_min = -30 * 3.14159265358979323846 / 180;          // grid limits, rad
  double elevation_max = 10 * 3.14159265358979323846 / 180;
  static OcclusionConfig for_fov(const FieldOfView& fov, double resolution_rad = 0.25 * 3.14159265358979323846 / 180);
};

class Occlusion {
 public:
  explicit Occlusion(const OcclusionConfig& config = {});

  // Objects and lanes in the sensor frame. Sets each object's visible_fraction; drops lane
  // points behind a box (lanes left with < 2 points are removed). Allocation-free once warm.
  // `trig`, when given, holds HeadingTrig::of(heading) per object (as apply_fov gives it).
  void apply(std::vector<Object>& objects, std::vector<LanePolyline>& lanes,
             const std::vector<HeadingTrig>* trig = nullptr);
  // The same with static scenery (sensor frame) in the depth test: a wall hides the objects and
  // lane points behind it. Scenery gets no visible fraction; footprint_cells() and
  // visible_cells() hold the objects' counts, then the scenery boxes'.
  void apply(std::vector<Object>& objects, std::vector<LanePolyline>& lanes, const std::vector<SceneryBox>& scenery,
             const std::vector<HeadingTrig>* trig = nullptr);

  // After apply(): per object (same order), cells of its footprint and cells it won.
  const std::vector<int>& footprint_cells() const { return footprint_; }
  const std::vector<int>& visible_cells() const { return visible_; }
  int rows() const { return rows_; }
  int cols() const { return cols_; }
  // The index owning each cell (-1 = none; objects first, then scenery) and its depth, [rows *
  // cols], row 0 = top.
  const std::vector<int>& owner() const { return owner_; }
  const std::vector<float>& depth() const { return depth_; }

 private:
  bool cell_of(const Eigen::Vector3d& p, int& row, int& col) const;
  void rasterise(const Eigen::Vector3d& position, const Eigen::Vector3d& size, int index, HeadingTrig h, double d_c);

  OcclusionConfig cfg_;
  int rows_ = 0, cols_ = 0;
  bool wide_ = false;  // raster spans take the AVX-512 kernel (nn/cpu_features.h), decided at construction
  std::vector<double> az_cos_, az_sin_, el_cos_, el_sin_, el_inv_cos_;
  std::vector<float> az_cos_f_, az_sin_f_;  // column directions over two turns (a box's run of columns never wraps)
  std::vector<float> col_in_, col_out_;     // per column of the box being rasterised: 2-D slab interval
  std::vector<std::pair<int, int>> written_;  // runs of cells (start, length) written this frame
  std::vector<int> order_;
  std::vector<double> key_, dist_;  // per object: sort key, horizontal distance of the centre
  std::vector<float> depth_;
  std::vector<int> owner_;
  std::vector<int> footprint_, visible_;
};

}  // namespace lidarsim::sensor
