#pragma once
// What a training step and a validation pass make of the datasets, a frame at a time
// (data::FrameSource), so no step needs more than its own frames in memory.
//
// The samples of a step are a pure function of (seed, epoch, step): the frame order of an epoch
// from (seed, epoch), each sample's crop offset and mirror from (seed, step). Nothing depends on
// which frames happen to be in memory, so a resumed run reads the same frames in the same order.
#include <cstdint>
#include <optional>
#include <utility>
#include <vector>

#include "data/baselines.h"
#include "data/frame_source.h"
#include "data/split.h"
#include "nn/tensor.h"
#include "nn/unet.h"
#include "pgm/encoder.h"

namespace lidarsim::train {

// One sample of a step: a frame (index over all training sets, in the order given), the source
// column its crop starts at, and whether the crop is mirrored.
struct Sample {
  int frame = 0;
  int offset = 0;
  bool mirror = false;
};

struct SamplePlan {
  int frames = 0;                    // over all training sets
  std::int64_t steps_per_epoch = 1;
  int batch = 1;
  int cols = 0, width = 0;           // grid columns; crop width (= cols: whole scans)
  bool roll = false, mirror = false;  // augmentation
  std::uint64_t seed = 1;
};

// Frame order of an epoch: a Fisher-Yates shuffle driven by (seed, epoch) alone.
std::vector<int> epoch_order(int frames, std::uint64_t seed, std::int64_t epoch);
// The plan.batch samples of `step`, in batch order (a data-parallel rank may take only its share).
std::vector<Sample> step_samples(const SamplePlan& plan, std::int64_t step);

// The training sets as one list of frames, each with the cells it trains on.
class TrainingFrames {
 public:
  // `split` empty: every cell with a return trains (a separate dataset validates); else cells of
  // validation and guard columns (per frame: SectorSplit::roles) do not, in the first
  // `split_sets` sets (-1: all); the sets after them train in every cell (other places).
  TrainingFrames(std::vector<const data::FrameSource*> sets, const pgm::EncoderConfig& encoder,
                 std::optional<data::SectorSplit> split, int split_sets = -1);
  int size() const { return total_; }
  int input_channels() const { return encoder_.input_channels(); }
  // Slot b of a batch: x [B, Cin, H, width] encoded input, y [B, 1, H, width] target, m the same
  // shape, 1 where a cell trains. Output column j is source column (offset + j) mod W, or
  // (offset + width - 1 - j) mod W mirrored; the crop is encoded after placing (the encoder works
  // cell by cell, so this equals cropping the encoded frame, bit for bit).
  void fill(const Sample& s, nn::Tensor& x, nn::Tensor& y, nn::Tensor& m, int b) const;

 private:
  std::pair<const data::FrameSource*, int> locate(int frame) const;

  std::vector<const data::FrameSource*> sets_;
  std::vector<int> first_;  // global index of each set's frame 0
  int total_ = 0;
  pgm::EncoderConfig encoder_;
  std::vector<std::string> raw_;  // the raw channels the encoder reads
  std::optional<data::SectorSplit> split_;
  int split_sets_ = -1;
};

// Validation metrics per set: the model predicts every frame of each set in turn, read one at a
// time (the next frame read and encoded on a background thread when `background`), and scores
// the cells `split` gives the validation role. Same numbers as evaluate_prediction on the set in
// memory.
std::vector<data::Metrics> validate_frames(nn::UNet& model, const pgm::EncoderConfig& encoder,
                                           const std::vector<const data::FrameSource*>& sets,
                                           const data::SectorSplit& split, bool background = true);

}  // namespace lidarsim::train
