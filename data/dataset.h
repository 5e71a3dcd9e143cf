#pragma once
// HDF5 datasets of Polar Grid Maps, readable with h5py:
//   /pgm          float32 [N, C, H, W]  raw channels (range m, class id, material id, and effect
//                                       channels such as elevation, azimuth, height, incidence)
//   /target       float32 [N, 1, H, W]  measured intensity (0 in empty cells)
//   /mask         uint8   [N, 1, H, W]  1 where the cell has a return
//   /point_index  int32   [N, H, W]     index of the point in its scan file (-1 empty), for
//                                       giving predictions back to the recorded points
//   /frames       strings [N]           frame ids, e.g. "semantickitti/00/000000"
//   /sources      strings [S]           every file the importer read
// Root attributes: format = "lidarsim-dataset", version = 1, channels (JSON list of the /pgm
// channel names), beam_layout (pgm::BeamLayout JSON), source_format ("semantickitti",
// "kitti_object", ...), row_modes (JSON list, per frame), target_channel = "intensity".
// Written to a temporary file and renamed (AtomicFile). Reading checks every dataset, attribute
// and shape and names the first that is missing or wrong.
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "nn/tensor.h"
#include "pgm/encoder.h"
#include "pgm/polar_grid_map.h"

namespace lidarsim::data {

struct Dataset {
  std::vector<std::string> channels;  // names of /pgm's channels
  pgm::BeamLayout layout;
  std::string source_format;
  std::vector<std::string> frames;     // one id per frame
  std::vector<std::string> row_modes;  // one per frame (pgm::to_string(RowMode))
  std::vector<std::string> sources;
  nn::Tensor pgm;     // [N, C, H, W]
  nn::Tensor target;  // [N, 1, H, W]
  nn::Tensor mask;    // [N, 1, H, W] 0/1 (uint8 in the file)
  std::vector<std::int32_t> point_index;  // [N * H * W]

  int size() const { return pgm.shape().n; }
  int rows() const { return pgm.shape().h; }
  int cols() const { return pgm.shape().w; }
  int channel_index(const std::string& name) const;  // throws naming the channel
  // Raw channels of frame n with the dataset's mask, ready for pgm::encode_input.
  pgm::ChannelView view(int n) const;
  // Frame n as a Polar Grid Map: the /pgm channels plus "intensity" (target) and "mask".
  pgm::PolarGridMap frame_pgm(int n) const;
  // Appends one projected frame: `channels` of the PGM go to /pgm, its "intensity" to /target,
  // its "mask" to /mask. The first frame fixes channels and layout; later ones must match.
  void append(const pgm::PolarGridMap& pgm, const std::string& frame_id, const std::string& row_mode);
};

// Every frame through the encoder: [N, config.input_channels(), H, W] (checks the channels first,
// naming `where` and the missing channel).
nn::Tensor encode_inputs(const Dataset& dataset, const pgm::EncoderConfig& config, const std::string& where = "dataset");

void write_dataset(const std::filesystem::path& path, const Dataset& dataset);

// `required_channels` (e.g. an encoder's inputs) must all be present in /pgm, else the error
// names the file and the missing channel.
Dataset read_dataset(const std::filesystem::path& path, const std::vector<std::string>& required_channels = {});

}  // namespace lidarsim::data
