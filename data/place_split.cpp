#include "data/place_split.h"

#include <set>

#include "common/error.h"
#include "data/frame_source.h"

namespace lidarsim::data {

PlacedSet read_placed_set(const std::string& name, const std::filesystem::path& path) {
  const auto source = open_frame_source(path);
  const Dataset& h = source->header();
  PlacedSet s{name, path, {}, source->rows(), source->cols(), h.intensity_scale};
  for (int n = 0; n < static_cast<int>(h.frames.size()); ++n) s.places.push_back(h.frame_place(n));
  return s;
}

std::string place_key(const FramePlace& p) { return p.source + "/" + p.sequence; }

namespace {

std::set<std::string> keys_of(const PlacedSet& s) {
  std::set<std::string> keys;
  for (const FramePlace& p : s.places) keys.insert(place_key(p));
  return keys;
}

}  // namespace

std::vector<PlaceFold> place_folds(const std::vector<PlacedSet>& sets) {
  std::set<std::string> names;
  for (const PlacedSet& s : sets) {
    if (!names.insert(s.name).second) throw Error("place folds: the name \"" + s.name + "\" is given twice");
    if (s.places.empty()) throw Error("place folds: " + s.name + " (" + s.path.string() + "): no frames");
  }
  std::vector<PlaceFold> folds;
  for (const PlacedSet& held : sets) {
    PlaceFold f{held.name, {}, {}};
    const std::set<std::string> held_keys = keys_of(held);
    for (const PlacedSet& s : sets) {
      if (&s == &held) continue;
      std::string why;  // every reason, so a reader sees all that keeps the set out
      auto add = [&](const std::string& reason) { why += (why.empty() ? "" : ", ") + reason; };
      for (const std::string& k : keys_of(s))
        if (held_keys.count(k)) add("holds frames of the held-out place " + k);
      if (s.rows != held.rows || s.cols != held.cols)
        add("grid " + std::to_string(s.rows) + " x " + std::to_string(s.cols) + ", not " + std::to_string(held.rows) +
            " x " + std::to_string(held.cols));
      if (!(s.scale == held.scale)) add("intensity scale " + s.scale.describe() + ", not " + held.scale.describe());
      if (why.empty())
        f.training.push_back(s.name);
      else
        f.excluded.push_back(s.name + ": " + why);
    }
    folds.push_back(f);
  }
  return folds;
}

void check_no_place_leak(const PlacedSet& held_out, const std::vector<PlacedSet>& training) {
  const std::set<std::string> held_keys = keys_of(held_out);
  for (const PlacedSet& s : training)
    for (std::size_t n = 0; n < s.places.size(); ++n)
      if (held_keys.count(place_key(s.places[n])))
        throw Error("held out by place: " + s.name + " (" + s.path.string() + ") frame " + std::to_string(n) + " (" +
                    s.places[n].frame + ") is from the held-out place " + place_key(s.places[n]) + " of " +
                    held_out.name);
}

}  // namespace lidarsim::data
