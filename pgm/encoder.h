#pragma once
// Network input from a Polar Grid Map's raw channels, and the target and mask tensors.
//
// Each configured input channel becomes one or more network channels:
//   "range"     -> 1 channel: range / range_max_m (empty cells 0)
//   "class"     -> one-hot over class groups (one channel per group, default
//                  pgm::default_class_groups()), or 1 channel class_id / class_count() when
//                  class_one_hot is false
//   "material"  -> one-hot over pgm::material ids, or 1 channel id / material_count()
//   "mask"      -> 1 channel, 1 where the cell has a return
//   any other   -> 1 channel: (value - offset) * scale, from `scales` (default offset 0, scale 1;
//                  built-in defaults: incidence / (pi/2), elevation and azimuth / pi,
//                  height / 3 m, x, y, z / range_max_m)
// Empty cells (mask 0) are 0 in every input channel, so the network sees "no return" the same
// way whatever the channel. The target is the raw `target` channel (intensity); the mask is 1 where
// the cell has a return (the loss and the metrics count only those cells).
//
// The whole configuration round-trips through to_json()/from_json(): it travels as a string in
// the checkpoint's /config attributes, so inference encodes exactly as training did.
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "nn/tensor.h"
#include "pgm/materials.h"
#include "pgm/polar_grid_map.h"

namespace lidarsim::pgm {

struct EncoderConfig {
  std::vector<std::string> channels = {"range", "class", "material"};
  std::string target = "intensity";
  float range_max_m = 80.f;
  bool class_one_hot = true;
  std::vector<ClassGroup> class_groups = default_class_groups();
  bool material_one_hot = true;
  std::map<std::string, std::pair<float, float>> scales;  // name -> (offset, scale), overrides defaults

  int input_channels() const;                    // number of network input channels
  std::vector<std::string> input_names() const;  // e.g. "range", "class:vehicle", "material:asphalt"
  std::string to_json() const;
  // `where` names the file/attribute the text came from; every field is checked.
  static EncoderConfig from_json(const std::string& text, const std::string& where = "encoder config");
  // Throws lidarsim::Error naming the first configured channel `available` lacks.
  void check_channels(const std::vector<std::string>& available, const std::string& where) const;
};

// A read-only view of raw channels [C, H, W] with their names (a PolarGridMap, or one image of a
// dataset's /pgm tensor).
struct ChannelView {
  const std::vector<std::string>* names = nullptr;
  const float* data = nullptr;  // [C, H, W]
  int rows = 0, cols = 0;
  const float* mask = nullptr;  // [H, W] 1 = return; if null, the "mask" channel is used
  const float* channel(const std::string& name, const std::string& where) const;
};
ChannelView view_of(const PolarGridMap& pgm);

// Writes image n of `out`, whose shape must be [N >= n+1, input_channels(), H, W].
void encode_input(const ChannelView& in, const EncoderConfig& config, nn::Tensor& out, int n);
// [1, input_channels(), H, W].
nn::Tensor encode_input(const PolarGridMap& pgm, const EncoderConfig& config);
// Target [1, 1, H, W] (the config's target channel, 0 in empty cells) and mask [1, 1, H, W] (0/1).
nn::Tensor encode_target(const PolarGridMap& pgm, const EncoderConfig& config);
nn::Tensor encode_mask(const PolarGridMap& pgm);

}  // namespace lidarsim::pgm
