// Planted return dropouts on measured scans: the return half of the loop's campaign of random
// planted effects (bench/loop_campaign_returns.cpp) and of its tests.
#include <algorithm>
#include <cmath>

#include "common/error.h"
#include "pgm/materials.h"
#include "qualify/returns/returns_loop.h"
#include "qualify/similarity.h"
#include "sensor/return_model.h"

namespace lidarsim::qualify {

const std::vector<PlantedReturnFamily>& all_planted_return_families() {
  static const std::vector<PlantedReturnFamily> f = {PlantedReturnFamily::LaserDropout, PlantedReturnFamily::ClassBeyondRange,
                                                      PlantedReturnFamily::AzimuthWindow, PlantedReturnFamily::Control};
  return f;
}

std::string to_string(PlantedReturnFamily f) {
  switch (f) {
    case PlantedReturnFamily::LaserDropout: return "laser_dropout";
    case PlantedReturnFamily::ClassBeyondRange: return "class_beyond_range";
    case PlantedReturnFamily::AzimuthWindow: return "azimuth_window";
    case PlantedReturnFamily::Control: return "control";
  }
  return "?";
}

PlantedReturnFamily planted_return_family_from_string(const std::string& name) {
  for (auto f : all_planted_return_families())
    if (to_string(f) == name) return f;
  throw Error("unknown planted return family \"" + name + "\" (expected laser_dropout, class_beyond_range, azimuth_window or control)");
}

double PlantedReturnEffect::keep_at(int row, double r, int cls, double azimuth_deg) const {
  switch (family) {
    case PlantedReturnFamily::LaserDropout: return row >= 0 && row < static_cast<int>(row_keep.size()) ? row_keep[row] : 1.0;
    case PlantedReturnFamily::ClassBeyondRange: return cls == class_id && r >= range_m ? keep : 1.0;
    case PlantedReturnFamily::AzimuthWindow: {
      const double d = std::fmod(azimuth_deg - azimuth_start_deg + 720.0, 360.0);
      return d < azimuth_width_deg ? keep : 1.0;
    }
    case PlantedReturnFamily::Control: return 1.0;
  }
  return 1.0;
}

PlantedReturnEffect draw_planted_returns(PlantedReturnFamily family, std::uint64_t seed, int rows,
                                         const std::vector<std::vector<float>>& class_ranges) {
  SplitMix rng(seed * 0x9E3779B97F4A7C15ULL + 77);
  auto uni = [&](double a, double b) { return a + (b - a) * rng.uniform(); };
  PlantedReturnEffect e;
  e.family = family;
  e.parameters = {{"family", to_string(family)}, {"seed", seed}};
  switch (family) {
    case PlantedReturnFamily::LaserDropout: {
      e.accepted = {"laser"};
      e.row_keep.assign(rows, 1.0);
      const int n = 1 + static_cast<int>(rng.next() % 4);
      std::vector<int> picked;
      while (static_cast<int>(picked.size()) < n) {
        const int r = static_cast<int>(rng.next() % rows);
        if (std::find(picked.begin(), picked.end(), r) == picked.end()) picked.push_back(r);
      }
      for (int r : picked) e.row_keep[r] = uni(0.3, 0.8);
      std::sort(picked.begin(), picked.end());
      e.parameters["lasers"] = picked;
      std::vector<double> keeps;
      for (int r : picked) keeps.push_back(e.row_keep[r]);
      e.parameters["keep"] = keeps;
      break;
    }
    case PlantedReturnFamily::ClassBeyondRange: {
      e.accepted = {"class x range", "class", "material"};
      double total = 0;
      for (const auto& v : class_ranges) total += v.size();
      std::vector<int> eligible;
      for (std::size_t c = 1; c < class_ranges.size(); ++c)
        if (total > 0 && class_ranges[c].size() >= 0.02 * total) eligible.push_back(static_cast<int>(c));
      if (eligible.empty()) throw Error("planted returns: no class holds 2 % of the returns (class_beyond_range needs labels)");
      e.class_id = eligible[rng.next() % eligible.size()];
      std::vector<float> r = class_ranges[e.class_id];
      std::sort(r.begin(), r.end());
      const double q = uni(0.2, 0.7);
      e.range_m = r[static_cast<std::size_t>(q * (r.size() - 1))];
      e.keep = uni(0.3, 0.7);
      e.parameters["class"] = pgm::class_name(e.class_id);
      e.parameters["beyond_m"] = e.range_m;
      e.parameters["quantile"] = q;
      e.parameters["keep"] = e.keep;
      break;
    }
    case PlantedReturnFamily::AzimuthWindow: {
      e.accepted = {"azimuth"};
      e.azimuth_start_deg = uni(0, 360);
      e.azimuth_width_deg = uni(20, 90);
      e.keep = uni(0.4, 0.8);
      e.parameters["start_deg"] = e.azimuth_start_deg;
      e.parameters["width_deg"] = e.azimuth_width_deg;
      e.parameters["keep"] = e.keep;
      break;
    }
    case PlantedReturnFamily::Control: break;
  }
  return e;
}

int plant_returns(pgm::PolarGridMap& map, const PlantedReturnEffect& effect, std::uint64_t seed, std::uint64_t scan) {
  if (effect.family == PlantedReturnFamily::Control) return 0;
  const float* range = map.channel("range");
  const float* cls = map.channel("class");
  const float* mask = map.channel("mask");
  const int C = static_cast<int>(map.channel_names().size());
  const int object_id = map.has_channel("object_id") ? map.channel_index("object_id") : -1;
  const int W = map.cols();
  int dropped = 0;
  for (std::size_t i = 0; i < map.cells(); ++i) {
    if (mask[i] < 0.5f) continue;
    const int row = static_cast<int>(i / W), col = static_cast<int>(i % W);
    const double keep = effect.keep_at(row, range[i], static_cast<int>(cls[i]), 360.0 * (col + 0.5) / W);
    if (keep >= 1 || sensor::return_draw(seed, scan, i) < keep) continue;
    ++dropped;
    for (int c = 0; c < C; ++c) map.channel(c)[i] = c == object_id ? -1.f : 0.f;
    map.point_index()[i] = -1;
  }
  return dropped;
}

}  // namespace lidarsim::qualify
