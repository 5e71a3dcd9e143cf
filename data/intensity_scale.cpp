#include "data/intensity_scale.h"

#include "data/rellis3d.h"

namespace lidarsim::data {

std::string IntensityScale::describe() const {
  if (!recorded()) return "not recorded";
  return normalisation.empty() ? name : name + " (" + normalisation + ")";
}

namespace intensity_scale {
// The names are part of the file format: datasets store them and lidar-train compares them.
IntensityScale kitti_reflectance() { return {"kitti_reflectance_0_1", "as recorded"}; }
IntensityScale nuscenes_intensity() { return {"nuscenes_intensity_0_255", "value / 255"}; }
IntensityScale ouster_reflectivity() { return {"ouster_reflectivity_0_255", "value / 255, capped at 1"}; }
IntensityScale rellis3d_reflectivity() {
  return {"rellis3d_reflectivity_16bit", "value / " + std::to_string(static_cast<int>(kRellisReflectivityScale)) + ", capped at 1"};
}
IntensityScale rellis3d_bin() { return {"rellis3d_bin_intensity", "as recorded"}; }
}  // namespace intensity_scale

std::string intensity_scale_conflict(const std::vector<std::pair<std::string, IntensityScale>>& named) {
  const std::pair<std::string, IntensityScale>* first = nullptr;
  for (const auto& n : named) {
    if (!n.second.recorded()) continue;
    if (!first) first = &n;
    else if (!(n.second == first->second))
      return first->first + " records " + first->second.describe() + "; " + n.first + " records " + n.second.describe();
  }
  return "";
}

}  // namespace lidarsim::data
