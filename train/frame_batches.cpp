#include "train/frame_batches.h"

#include <algorithm>
#include <numeric>

#include "common/counter_hash.h"
#include "common/error.h"
#include "train/prefetcher.h"

namespace lidarsim::train {
namespace {

int channel_of(const data::FrameSource& set, const std::string& name) {
  const auto& have = set.header().channels;
  const auto it = std::find(have.begin(), have.end(), name);
  if (it == have.end()) {
    std::string list;
    for (const auto& a : have) list += (list.empty() ? "" : ", ") + a;
    throw input_error(set.name(), "/pgm channel '" + name + "'", "missing (the set has: " + list + ")");
  }
  return static_cast<int>(it - have.begin());
}

std::string frame_id(const data::FrameSource& set, int n) {
  const auto& ids = set.header().frames;
  return n < static_cast<int>(ids.size()) ? ids[static_cast<std::size_t>(n)] : "";
}

}  // namespace

std::vector<int> epoch_order(int frames, std::uint64_t seed, std::int64_t epoch) {
  std::vector<int> order(static_cast<std::size_t>(frames));
  std::iota(order.begin(), order.end(), 0);
  std::uint64_t state = splitmix64(seed ^ splitmix64(static_cast<std::uint64_t>(epoch) + 0x51ed));
  for (int i = frames - 1; i > 0; --i) {
    state = splitmix64(state);
    std::swap(order[static_cast<std::size_t>(i)], order[state % static_cast<std::uint64_t>(i + 1)]);
  }
  return order;
}

std::vector<Sample> step_samples(const SamplePlan& p, std::int64_t step) {
  const std::int64_t epoch = step / p.steps_per_epoch;
  const std::vector<int> order = epoch_order(p.frames, p.seed, epoch);
  const std::int64_t in_epoch = step % p.steps_per_epoch;
  std::uint64_t rng = splitmix64(p.seed * kSplitMixGamma ^ static_cast<std::uint64_t>(step));
  std::vector<Sample> samples(static_cast<std::size_t>(p.batch));
  for (int b = 0; b < p.batch; ++b) {
    Sample& s = samples[static_cast<std::size_t>(b)];
    s.frame = order[static_cast<std::size_t>((in_epoch * p.batch + b) % p.frames)];
    rng = splitmix64(rng);
    s.offset = p.roll ? static_cast<int>(rng % static_cast<std::uint64_t>(p.cols))
                      : (p.width < p.cols ? static_cast<int>(rng % (p.cols - p.width + 1)) : 0);
    rng = splitmix64(rng);
    s.mirror = p.mirror && (rng & 1);
  }
  return samples;
}

TrainingFrames::TrainingFrames(std::vector<const data::FrameSource*> sets, const pgm::EncoderConfig& encoder,
                               std::optional<data::SectorSplit> split, int split_sets)
    : sets_(std::move(sets)), encoder_(encoder), split_(std::move(split)), split_sets_(split_sets) {
  for (const auto& c : encoder_.channels)
    if (c != "mask") raw_.push_back(c);
  for (const data::FrameSource* set : sets_) {
    for (const auto& c : raw_) channel_of(*set, c);  // refuse a missing channel now, naming the set
    first_.push_back(total_);
    total_ += set->size();
  }
}

std::pair<const data::FrameSource*, int> TrainingFrames::locate(int frame) const {
  if (frame < 0 || frame >= total_)
    throw Error("training frame " + std::to_string(frame) + " out of range (" + std::to_string(total_) + " frames)");
  const auto set = static_cast<std::size_t>(std::upper_bound(first_.begin(), first_.end(), frame) - first_.begin()) - 1;
  return {sets_[set], frame - first_[set]};
}

void TrainingFrames::fill(const Sample& s, nn::Tensor& x, nn::Tensor& y, nn::Tensor& m, int b) const {
  const auto [set, n] = locate(s.frame);
  const data::FrameRef f = set->frame(n);
  const int rows = set->rows(), cols = set->cols(), width = x.shape().w;
  const std::size_t plane = static_cast<std::size_t>(rows) * cols, crop = static_cast<std::size_t>(rows) * width;
  std::vector<int> column(static_cast<std::size_t>(width));
  for (int j = 0; j < width; ++j) {
    const int k = s.mirror ? s.offset + width - 1 - j : s.offset + j;
    column[static_cast<std::size_t>(j)] = ((k % cols) + cols) % cols;
  }
  std::vector<std::uint8_t> roles;
  const auto set_index = std::upper_bound(first_.begin(), first_.end(), s.frame) - first_.begin() - 1;
  const bool follows_split = split_ && (split_sets_ < 0 || set_index < split_sets_);
  if (follows_split) roles = split_->roles(cols, frame_id(*set, n));
  // Only the channels the encoder reads are copied into the crop. Scratch kept per thread: a
  // fresh allocation each sample costs more in page faults than the copying.
  thread_local std::vector<float> raw, mask;
  raw.resize(raw_.size() * crop);
  mask.resize(crop);
  for (std::size_t c = 0; c < raw_.size(); ++c) {
    const float* in = f.pgm + static_cast<std::size_t>(channel_of(*set, raw_[c])) * plane;
    float* out = raw.data() + c * crop;
    for (int r = 0; r < rows; ++r)
      for (int j = 0; j < width; ++j)
        out[static_cast<std::size_t>(r) * width + j] = in[static_cast<std::size_t>(r) * cols + column[j]];
  }
  float* target = y.channel(b, 0);
  float* train = m.channel(b, 0);
  for (int r = 0; r < rows; ++r)
    for (int j = 0; j < width; ++j) {
      const std::size_t i = static_cast<std::size_t>(r) * cols + column[j], o = static_cast<std::size_t>(r) * width + j;
      target[o] = f.target[i];
      mask[o] = f.mask[i];
      const bool held_out = follows_split && roles[column[j]] != data::kTrain;  // validation or guard
      train[o] = (f.mask[i] > 0 && !held_out) ? 1.f : 0.f;
    }
  pgm::ChannelView view;
  view.names = &raw_;
  view.data = raw.data();
  view.rows = rows;
  view.cols = width;
  view.mask = mask.data();
  pgm::encode_input(view, encoder_, x, b);
}

std::vector<data::Metrics> validate_frames(nn::UNet& model, const pgm::EncoderConfig& encoder,
                                           const std::vector<const data::FrameSource*>& sets,
                                           const data::SectorSplit& split, bool background) {
  struct Item {
    data::FrameRef frame;
    nn::Tensor input;
    std::vector<std::uint8_t> roles;
    std::size_t set = 0;
  };
  std::vector<std::pair<std::size_t, int>> order;  // (set, frame) in the order evaluate_prediction takes them
  for (std::size_t s = 0; s < sets.size(); ++s)
    for (int n = 0; n < sets[s]->size(); ++n) order.emplace_back(s, n);
  Prefetcher<Item> frames(
      [&](std::int64_t k, Item& item) {
        const auto [s, n] = order[static_cast<std::size_t>(k)];
        const data::FrameSource& set = *sets[s];
        item.frame = set.frame(n);
        item.input.resize({1, encoder.input_channels(), set.rows(), set.cols()});
        pgm::encode_input(set.view(item.frame), encoder, item.input, 0);
        item.roles = split.roles(set.cols(), frame_id(set, n));
        item.set = s;
      },
      0, static_cast<std::int64_t>(order.size()), background);
  std::vector<data::ErrorSums> sums(sets.size());
  nn::Tensor prediction;
  for (std::size_t k = 0; k < order.size(); ++k) {
    Item& item = frames.next();
    model.predict(item.input, prediction);
    const data::FrameSource& set = *sets[item.set];
    data::add_frame_errors(sums[item.set], prediction.data(), item.frame.target, item.frame.mask, item.roles,
                           set.rows(), set.cols(), true);
  }
  std::vector<data::Metrics> metrics;
  for (const auto& s : sums) metrics.push_back(s.get());
  return metrics;
}

}  // namespace lidarsim::train
