#pragma once
// Polar Grid Map: a range image with named float channels, rows = beams, columns = azimuth bins.
// Channels hold raw values (range in m, class id, material id, intensity, mask 0/1, effect
// channels such as incidence, elevation, azimuth, height); pgm/encoder.h turns them into network
// input. Every cell also remembers which input point it holds (-1 when empty) so predictions can
// be given back to points.
#include <cstdint>
#include <string>
#include <vector>

#include "pgm/beam_layout.h"

namespace lidarsim::pgm {

class PolarGridMap {
 public:
  PolarGridMap() = default;
  PolarGridMap(BeamLayout layout, std::vector<std::string> channels);

  const BeamLayout& layout() const { return layout_; }
  int rows() const { return layout_.rows(); }
  int cols() const { return layout_.columns; }
  const std::vector<std::string>& channel_names() const { return names_; }
  bool has_channel(const std::string& name) const;
  int channel_index(const std::string& name) const;  // throws lidarsim::Error naming the channel
  int add_channel(const std::string& name);          // zero-filled; returns its index

  float* channel(int c) { return data_.data() + static_cast<std::size_t>(c) * cells(); }
  const float* channel(int c) const { return data_.data() + static_cast<std::size_t>(c) * cells(); }
  float* channel(const std::string& name) { return channel(channel_index(name)); }
  const float* channel(const std::string& name) const { return channel(channel_index(name)); }
  float& at(int c, int row, int col) { return channel(c)[static_cast<std::size_t>(row) * cols() + col]; }
  float at(int c, int row, int col) const { return channel(c)[static_cast<std::size_t>(row) * cols() + col]; }

  std::size_t cells() const { return static_cast<std::size_t>(rows()) * cols(); }
  std::vector<std::int64_t>& point_index() { return point_index_; }  // [rows * cols], -1 = empty
  const std::vector<std::int64_t>& point_index() const { return point_index_; }
  const std::vector<float>& data() const { return data_; }  // [C, rows, cols]

 private:
  BeamLayout layout_;
  std::vector<std::string> names_;
  std::vector<float> data_;
  std::vector<std::int64_t> point_index_;
};

}  // namespace lidarsim::pgm
