#pragma once
// HDF5 datasets of Polar Grid Maps, readable with h5py:
//   /pgm          float32 [N, C, H, W]  raw channels (range m, class id, material id, effect
//                                       channels such as elevation, azimuth, height, incidence,
//                                       and label channels a reader adds: motion, data/semantickitti_mos.h)
//   /target       float32 [N, 1, H, W]  measured intensity (0 in empty cells)
//   /mask         uint8   [N, 1, H, W]  1 where the cell has a return
//   /point_index  int32   [N, H, W]     index of the point in its scan file (-1 empty), for
//                                       giving predictions back to the recorded points
//   /frames       strings [N]           frame ids, e.g. "semantickitti/00/000000"
//   /sources      strings [S]           every file the importer read
//   /row_modes    strings [N]           pgm::RowMode used per frame
//   /place_source, /place_sequence, /place_frame  strings [N]  where each frame was recorded
//                                       (FramePlace), so splits can hold out whole places
// Root attributes: format = "lidarsim-dataset", version = 2, channels (JSON list of the /pgm
// channel names), beam_layout (pgm::BeamLayout JSON), source_format ("semantickitti",
// "kitti_object", ...), row_modes (JSON list, per frame; only while short enough for an
// attribute — version 1 files have only this), target_channel = "intensity", and, when the
// importer knows them, intensity_scale and intensity_normalisation (data/intensity_scale.h).
// Frame arrays are chunked one frame per chunk, shuffled and deflated (DatasetWriter streams
// them; DatasetReader reads single frames back). Written to a temporary file and renamed
// (AtomicFile). Reading checks every dataset, attribute and shape and names the first that is
// missing or wrong.
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "data/intensity_scale.h"
#include "nn/tensor.h"
#include "pgm/encoder.h"
#include "pgm/polar_grid_map.h"

namespace lidarsim::data {

// Where a frame was recorded: format ("semantickitti", "nuscenes", "rellis3d", "ouster", ...),
// sequence / drive / log / recording (empty when the source does not say), and the frame's id
// within it. Frames of one (source, sequence) come from one drive, so they share a place.
struct FramePlace {
  std::string source;
  std::string sequence;
  std::string frame;
  bool operator==(const FramePlace&) const = default;
};

// "format/sequence/frame" -> {format, sequence, frame}; "format/frame" -> {format, "", frame};
// an id without '/' -> {source_format, "", id}.
FramePlace place_from_frame_id(const std::string& id, const std::string& source_format);

struct Dataset {
  std::vector<std::string> channels;  // names of /pgm's channels
  pgm::BeamLayout layout;
  std::string source_format;
  IntensityScale intensity_scale;      // not recorded in files written before it existed
  std::vector<std::string> frames;     // one id per frame
  std::vector<std::string> row_modes;  // one per frame (pgm::to_string(RowMode))
  std::vector<std::string> sources;
  std::vector<FramePlace> places;  // one per frame (empty for version 1 files: see frame_place)
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
  // Where frame n was recorded. Files written before places were stored: parsed from the frame
  // id ("format/sequence/frame" or "format/frame"), the sequence empty when the id has none.
  FramePlace frame_place(int n) const;
  // Appends one projected frame: `channels` of the PGM go to /pgm, its "intensity" to /target,
  // its "mask" to /mask. The first frame fixes channels and layout; later ones must match.
  // Frames are copied, so this suits small in-memory sets; imports stream to DatasetWriter.
  void append(const pgm::PolarGridMap& pgm, const std::string& frame_id, const std::string& row_mode,
              const FramePlace& place = {});
};

// Every frame through the encoder: [N, config.input_channels(), H, W] (checks the channels first,
// naming `where` and the missing channel).
nn::Tensor encode_inputs(const Dataset& dataset, const pgm::EncoderConfig& config, const std::string& where = "dataset");

// Through DatasetWriter; the tensors' grid must match the beam layout.
void write_dataset(const std::filesystem::path& path, const Dataset& dataset);

// `required_channels` (e.g. an encoder's inputs) must all be present in /pgm, else the error
// names the file and the missing channel.
// Loads every frame (through DatasetReader); for files too large for memory read frames lazily.
Dataset read_dataset(const std::filesystem::path& path, const std::vector<std::string>& required_channels = {});

}  // namespace lidarsim::data
