#pragma once
// What a dataset's intensity means. Every reader writes /target on 0-1, but 0-1 of KITTI's
// reflectance is not 0-1 of nuScenes' 8-bit intensity, of an Ouster's reflectivity counts or of
// RELLIS-3D's 16-bit reflectivity: a model trained on a mix would learn an average of unrelated
// scales. Import records the source's scale and how it was brought to 0-1 as root attributes
// (intensity_scale, intensity_normalisation); lidar-train refuses to mix datasets whose recorded
// scales differ unless told to. Files written before these attributes existed have none: their
// scale reads as not recorded and is compared with nothing (they load and mix as they always did).
#include <string>
#include <utility>
#include <vector>

namespace lidarsim::data {

struct IntensityScale {
  std::string name;           // the recorded quantity and its range, e.g. "kitti_reflectance_0_1"
  std::string normalisation;  // how /target was made from it, e.g. "value / 255"
  bool recorded() const { return !name.empty(); }
  bool operator==(const IntensityScale&) const = default;
  std::string describe() const;  // "name (normalisation)", or "not recorded"
};

// The scales the importers write (data/import.cpp picks one per format and scan).
namespace intensity_scale {
IntensityScale kitti_reflectance();     // KITTI HDL-64E .bin reflectance, already 0-1
IntensityScale nuscenes_intensity();    // nuScenes LIDAR_TOP intensity 0-255
IntensityScale ouster_reflectivity();   // Ouster calibrated reflectivity 0-255
IntensityScale rellis3d_reflectivity(); // RELLIS-3D OS1-64 PLY reflectivity, 16-bit counts
IntensityScale rellis3d_bin();          // RELLIS-3D .bin intensity (rescaled, max ~0.01), no PLY
}  // namespace intensity_scale

// The first pair of datasets whose recorded scales differ, as "A records X; B records Y";
// empty when all recorded scales agree. Datasets without a recorded scale are not compared.
std::string intensity_scale_conflict(const std::vector<std::pair<std::string, IntensityScale>>& named);

}  // namespace lidarsim::data
