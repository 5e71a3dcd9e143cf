#include "pgm/polar_grid_map.h"

#include <algorithm>

#include "common/error.h"

namespace lidarsim::pgm {

PolarGridMap::PolarGridMap(BeamLayout layout, std::vector<std::string> channels) : layout_(std::move(layout)) {
  layout_.validate("polar grid map");
  for (const auto& name : channels) add_channel(name);
  point_index_.assign(cells(), -1);
}

bool PolarGridMap::has_channel(const std::string& name) const {
  return std::find(names_.begin(), names_.end(), name) != names_.end();
}

int PolarGridMap::channel_index(const std::string& name) const {
  auto it = std::find(names_.begin(), names_.end(), name);
  if (it == names_.end()) {
    std::string have;
    for (const auto& n : names_) have += (have.empty() ? "" : ", ") + n;
    throw Error("polar grid map: channel '" + name + "': not present (channels: " + have + ")");
  }
  return static_cast<int>(it - names_.begin());
}

int PolarGridMap::add_channel(const std::string& name) {
  if (name.empty()) throw Error("polar grid map: channel name: must not be empty");
  if (has_channel(name)) throw Error("polar grid map: channel '" + name + "': already present");
  names_.push_back(name);
  data_.resize(names_.size() * cells(), 0.f);
  return static_cast<int>(names_.size()) - 1;
}

}  // namespace lidarsim::pgm
