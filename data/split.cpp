#include "data/split.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <string>

#include "common/error.h"

namespace lidarsim::data {

namespace {

int wrap(int c, int columns) { return ((c % columns) + columns) % columns; }

// Validation columns of the region split (before guards).
std::vector<std::uint8_t> region_columns(const SectorSplit& s, int columns) {
  std::vector<std::uint8_t> v(columns, 0);
  for (const auto& [b, e] : s.regions) {
    const int cb = static_cast<int>(std::lround(b * columns)), ce = static_cast<int>(std::lround(e * columns));
    for (int c = cb; c < ce; ++c) v[wrap(c, columns)] = 1;
  }
  return v;
}

}  // namespace

int SectorSplit::sector_of(int column, int columns) const {
  if (sectors < 1 || columns < sectors || columns % sectors != 0)
    throw Error("split: columns: " + std::to_string(columns) + " is not a multiple of the " +
                std::to_string(sectors) + " sectors");
  if (column < 0 || column >= columns) throw Error("split: column " + std::to_string(column) + " out of range");
  return column / (columns / sectors);
}

bool SectorSplit::is_validation(int column, int columns) const {
  if (!regions.empty()) {
    if (column < 0 || column >= columns) throw Error("split: column " + std::to_string(column) + " out of range");
    return region_columns(*this, columns)[column] != 0;
  }
  const int s = sector_of(column, columns);
  return std::find(validation.begin(), validation.end(), s) != validation.end();
}

std::vector<std::uint8_t> SectorSplit::validation_columns(int columns) const {
  const auto r = roles(columns);
  std::vector<std::uint8_t> out(columns);
  for (int c = 0; c < columns; ++c) out[c] = r[c] == kValidation ? 1 : 0;
  return out;
}

std::vector<std::uint8_t> SectorSplit::roles(int columns, const std::string& frame_id) const {
  if (!validation_frames.empty()) {
    bool held = false;
    for (const auto& id : validation_frames)
      held = held || (frame_id.size() >= id.size() && frame_id.compare(frame_id.size() - id.size(), id.size(), id) == 0);
    return std::vector<std::uint8_t>(columns, held ? kValidation : kTrain);
  }
  std::vector<std::uint8_t> r(columns, kTrain);
  if (regions.empty()) {
    for (int c = 0; c < columns; ++c) r[c] = is_validation(c, columns) ? kValidation : kTrain;
  } else {
    const auto v = region_columns(*this, columns);
    for (int c = 0; c < columns; ++c) r[c] = v[c] ? kValidation : kTrain;
  }
  if (guard_columns > 0)
    for (int c = 0; c < columns; ++c) {
      if (r[c] != kValidation) continue;
      for (int d = -guard_columns; d <= guard_columns; ++d) {
        auto& g = r[wrap(c + d, columns)];
        if (g == kTrain) g = kGuard;
      }
    }
  return r;
}

int SectorSplit::region_of(int column, int columns) const {
  if (regions.empty()) return is_validation(column, columns) ? sector_of(column, columns) : -1;
  for (std::size_t k = 0; k < regions.size(); ++k) {
    const int cb = static_cast<int>(std::lround(regions[k].first * columns));
    const int ce = static_cast<int>(std::lround(regions[k].second * columns));
    for (int c = cb; c < ce; ++c)
      if (wrap(c, columns) == column) return static_cast<int>(k);
  }
  return -1;
}

std::string SectorSplit::describe(int columns) const {
  std::ostringstream s;
  if (!validation_frames.empty()) {
    s << "frames held out whole (validation): ";
    for (std::size_t i = 0; i < validation_frames.size(); ++i) s << (i ? ", " : "") << validation_frames[i];
    s << "; all other frames train";
    return s.str();
  }
  if (regions.empty()) {
    s << name << ": sectors";
    for (int v : validation) s << " " << v;
    s << " of " << sectors << " validate in every scan, no guard band (leaks: kept for comparison only)";
    return s.str();
  }
  const auto r = roles(columns);
  s << name << ": validation columns";
  for (const auto& [b, e] : regions) s << " [" << std::lround(b * columns) << ", " << std::lround(e * columns) << ")";
  s << " of " << columns << " in every scan, guard bands of " << guard_columns
    << " columns on each side (no training loss, not scored); " << std::count(r.begin(), r.end(), kTrain)
    << " training, " << std::count(r.begin(), r.end(), kValidation) << " validation, "
    << std::count(r.begin(), r.end(), kGuard) << " guard columns";
  return s.str();
}

SectorSplit guarded_split(int half_width, int columns) {
  if (half_width < 0 || columns < 16) throw Error("guarded split: half-width and columns out of range");
  SectorSplit s;
  s.name = "guarded";
  s.guard_columns = 2 * half_width;
  const int g = s.guard_columns;
  const int need_two = 2 * (columns / 8 + 2 * g), need_one = columns / 4 + 2 * g;
  const int train_min = columns / 4;
  if (need_two <= columns - train_min) {
    s.regions = {{0.125 - 1.0 / 16, 0.125 + 1.0 / 16}, {0.625 - 1.0 / 16, 0.625 + 1.0 / 16}};
  } else if (need_one <= columns - train_min) {
    s.regions = {{0.0, 0.25}};
  } else {
    throw Error("guarded split: a receptive-field half-width of " + std::to_string(half_width) +
                " columns leaves too few training columns out of " + std::to_string(columns) +
                " (guard bands of twice the half-width on each side of a quarter of the circle)");
  }
  return s;
}

SectorSplit inner_split(const SectorSplit& scored, int half_width, int columns, int width) {
  if (scored.regions.empty() || !scored.validation_frames.empty() || scored.guard_columns < 2 * half_width)
    throw Error("inner split: needs a guarded region split (guard bands of at least twice the half-width), got " +
                scored.describe(columns));
  if (width < 1) throw Error("inner split: width must be at least 1 column, got " + std::to_string(width));
  const auto roles = scored.roles(columns);
  // The longest run of training columns (circular), found from a column that is not training.
  int start = -1;
  for (int c = 0; c < columns; ++c)
    if (roles[c] != kTrain) start = c;
  if (start < 0) throw Error("inner split: the split holds nothing out");
  int best_begin = 0, best_len = 0;
  for (int k = 1, run = 0; k <= columns; ++k) {
    const int c = wrap(start + k, columns);
    run = roles[c] == kTrain ? run + 1 : 0;
    if (run > best_len) best_len = run, best_begin = wrap(c - run + 1, columns);
  }
  const int band = 2 * half_width;
  if (width + band + width > best_len)
    throw Error("inner split: an inner region of " + std::to_string(width) + " columns and its guard band of " +
                std::to_string(band) + " leave fewer than " + std::to_string(width) +
                " training columns in the longest training arc (" + std::to_string(best_len) + " columns)");
  SectorSplit inner;
  inner.name = "inner";
  inner.guard_columns = band;
  inner.regions = {{static_cast<double>(best_begin) / columns, static_cast<double>(best_begin + width) / columns}};
  return inner;
}

SectorSplit inner_frames_split(const SectorSplit& scored, const std::vector<std::string>& ids) {
  if (scored.validation_frames.empty()) throw Error("inner split: inner frames need a frame hold-out (--split frames:...)");
  if (ids.empty()) throw Error("inner split: no inner frames given");
  for (const auto& id : ids)
    for (const auto& held : scored.validation_frames)
      if (id.empty() || (id.size() >= held.size() ? id.compare(id.size() - held.size(), held.size(), held) == 0
                                                 : held.compare(held.size() - id.size(), id.size(), id) == 0))
        throw Error("inner split: inner frame \"" + id + "\" is (or names) the scored frame \"" + held + "\"");
  SectorSplit inner;
  inner.name = "inner frames";
  inner.validation_frames = ids;
  return inner;
}

SectorSplit with_inner(const SectorSplit& scored, const SectorSplit& inner) {
  SectorSplit s = scored;
  s.name = scored.name + " + inner";
  s.validation_frames.insert(s.validation_frames.end(), inner.validation_frames.begin(), inner.validation_frames.end());
  s.regions.insert(s.regions.end(), inner.regions.begin(), inner.regions.end());
  s.guard_columns = std::max(scored.guard_columns, inner.guard_columns);
  return s;
}

SectorSplit parse_split(const std::string& spec, int half_width, int columns) {
  if (spec == "interleaved") return reference_split();
  if (spec == "guarded") return guarded_split(half_width, columns);
  if (spec.rfind("guarded:", 0) == 0) {
    try {
      std::size_t used = 0;
      const int h = std::stoi(spec.substr(8), &used);
      if (used == spec.size() - 8) return guarded_split(h, columns);
    } catch (const std::logic_error&) {
    }
    throw Error("--split \"" + spec + "\": expected guarded:<half-width in columns>");
  }
  if (spec.rfind("frames:", 0) == 0) {
    SectorSplit s;
    s.name = "frames";
    std::stringstream ss(spec.substr(7));
    for (std::string id; std::getline(ss, id, ',');)
      if (!id.empty()) s.validation_frames.push_back(id);
    if (s.validation_frames.empty()) throw Error("--split \"" + spec + "\": no frame ids after frames:");
    return s;
  }
  throw Error("--split \"" + spec + "\": unknown (expected guarded, guarded:<half-width>, interleaved or frames:<id>,...)");
}

}  // namespace lidarsim::data
