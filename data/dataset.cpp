#include "data/dataset.h"

#include <algorithm>

#include "common/error.h"
#include "data/dataset_reader.h"
#include "data/dataset_writer.h"

namespace lidarsim::data {
namespace fs = std::filesystem;


int Dataset::channel_index(const std::string& name) const {
  auto it = std::find(channels.begin(), channels.end(), name);
  if (it == channels.end()) throw Error("dataset: channel '" + name + "': missing");
  return static_cast<int>(it - channels.begin());
}

pgm::ChannelView Dataset::view(int n) const {
  pgm::ChannelView v;
  v.names = &channels;
  v.data = pgm.image(n);
  v.rows = rows();
  v.cols = cols();
  v.mask = mask.image(n);
  return v;
}

pgm::PolarGridMap Dataset::frame_pgm(int n) const {
  std::vector<std::string> names = channels;
  names.push_back("intensity");
  names.push_back("mask");
  pgm::PolarGridMap out(layout, names);
  const std::size_t plane = static_cast<std::size_t>(rows()) * cols();
  for (int c = 0; c < static_cast<int>(channels.size()); ++c)
    std::copy(pgm.channel(n, c), pgm.channel(n, c) + plane, out.channel(c));
  std::copy(target.image(n), target.image(n) + plane, out.channel("intensity"));
  std::copy(mask.image(n), mask.image(n) + plane, out.channel("mask"));
  if (!point_index.empty())
    for (std::size_t i = 0; i < plane; ++i) out.point_index()[i] = point_index[n * plane + i];
  return out;
}

FramePlace place_from_frame_id(const std::string& id, const std::string& source_format) {
  const auto first = id.find('/'), last = id.rfind('/');
  if (first == std::string::npos) return {source_format, "", id};
  if (first == last) return {id.substr(0, first), "", id.substr(first + 1)};
  return {id.substr(0, first), id.substr(first + 1, last - first - 1), id.substr(last + 1)};
}

FramePlace Dataset::frame_place(int n) const {
  if (n < 0 || n >= static_cast<int>(frames.size())) throw Error("dataset: frame " + std::to_string(n) + ": out of range");
  if (places.size() == frames.size()) return places[n];
  return place_from_frame_id(frames[n], source_format);
}

void Dataset::append(const pgm::PolarGridMap& map, const std::string& frame_id, const std::string& row_mode,
                     const FramePlace& place) {
  if (frames.empty()) {
    layout = map.layout();
  } else if (!(map.layout() == layout)) {
    throw Error("dataset: frame " + frame_id + ": beam layout differs from the first frame's");
  }
  if (channels.empty()) throw Error("dataset: channels: set the /pgm channel names before appending frames");
  const int n = size(), C = static_cast<int>(channels.size()), H = map.rows(), W = map.cols();
  if (n > 0 && (H != rows() || W != cols())) throw Error("dataset: frame " + frame_id + ": grid size differs");
  // Grow by copying (imports are small; this keeps the tensors contiguous for training).
  auto grow = [&](nn::Tensor& t, int c) {
    nn::Tensor bigger(n + 1, c, H, W);
    if (n > 0) std::copy(t.begin(), t.end(), bigger.begin());
    t = std::move(bigger);
  };
  grow(pgm, C);
  grow(target, 1);
  grow(mask, 1);
  const std::size_t plane = static_cast<std::size_t>(H) * W;
  for (int c = 0; c < C; ++c) {
    const float* src = map.channel(channels[c]);
    std::copy(src, src + plane, pgm.channel(n, c));
  }
  const float* intensity = map.channel("intensity");
  const float* m = map.channel("mask");
  std::copy(intensity, intensity + plane, target.image(n));
  std::copy(m, m + plane, mask.image(n));
  for (std::size_t i = 0; i < plane; ++i) point_index.push_back(static_cast<std::int32_t>(map.point_index()[i]));
  if (places.size() == frames.size())
    places.push_back(place.source.empty() ? place_from_frame_id(frame_id, source_format) : place);
  frames.push_back(frame_id);
  row_modes.push_back(row_mode);
}

nn::Tensor encode_inputs(const Dataset& d, const pgm::EncoderConfig& config, const std::string& where) {
  std::vector<std::string> available = d.channels;
  available.push_back("intensity");  // the target lives in /target
  config.check_channels(available, where);
  if (config.target != "intensity")
    throw input_error(where, "encoder target '" + config.target + "'", "datasets carry only intensity as target");
  nn::Tensor out(d.size(), config.input_channels(), d.rows(), d.cols());
  for (int n = 0; n < d.size(); ++n) pgm::encode_input(d.view(n), config, out, n);
  return out;
}

void write_dataset(const fs::path& path, const Dataset& d) {
  const std::string fname = path.string();
  const int N = d.size(), C = static_cast<int>(d.channels.size()), H = d.rows(), W = d.cols();
  if (d.pgm.shape().c != C && N > 0) throw input_error(fname, "/pgm", "channel count differs from the channel names");
  if (static_cast<int>(d.frames.size()) != N || static_cast<int>(d.row_modes.size()) != N)
    throw input_error(fname, "/frames", "one frame id and row mode per frame expected");
  if (N > 0 && (H != d.layout.rows() || W != d.layout.columns))
    throw input_error(fname, "/pgm", "grid " + std::to_string(H) + " x " + std::to_string(W) +
                                         " differs from the beam layout's " + std::to_string(d.layout.rows()) + " x " +
                                         std::to_string(d.layout.columns));
  const std::size_t plane = static_cast<std::size_t>(H) * W;
  if (!d.point_index.empty() && d.point_index.size() != static_cast<std::size_t>(N) * plane)
    throw input_error(fname, "/point_index", "size differs from N x H x W");
  DatasetWriter out(path, d.channels, d.layout, d.source_format, !d.point_index.empty());
  out.set_intensity_scale(d.intensity_scale);
  for (int n = 0; n < N; ++n)
    out.append(d.pgm.image(n), d.target.image(n), d.mask.image(n),
               d.point_index.empty() ? nullptr : d.point_index.data() + n * plane, d.frames[n], d.row_modes[n],
               d.frame_place(n));
  for (const auto& s : d.sources) out.add_source(s);
  out.commit();
}

namespace {

Dataset read_all(const DatasetReader& in) {
  Dataset d = in.header();
  const int N = in.size(), C = in.channels(), H = in.rows(), W = in.cols();
  d.pgm.resize({N, C, H, W});
  d.target.resize({N, 1, H, W});
  d.mask.resize({N, 1, H, W});
  const std::size_t plane = static_cast<std::size_t>(H) * W;
  if (in.has_point_index() && N > 0) d.point_index.resize(N * plane);
  for (int n = 0; n < N; ++n)
    in.read_frame(n, d.pgm.image(n), d.target.image(n), d.mask.image(n),
                  in.has_point_index() ? d.point_index.data() + n * plane : nullptr);
  return d;
}

}  // namespace

Dataset read_dataset(const fs::path& path, const std::vector<std::string>& required_channels) {
  return read_all(DatasetReader(path, required_channels));
}

Dataset read_dataset(const nn::MemoryImage& image, const std::vector<std::string>& required_channels) {
  return read_all(DatasetReader(image, required_channels));
}

}  // namespace lidarsim::data
