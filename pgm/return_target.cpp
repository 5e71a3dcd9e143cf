#include "pgm/return_target.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "common/angles.h"
#include "common/error.h"

namespace lidarsim::pgm {

const char* to_string(ReturnRule rule) {
  switch (rule) {
    case ReturnRule::Measured: return "measured";
    case ReturnRule::RowGap: return "row_gap";
    case ReturnRule::BelowReturn: return "below_return";
    case ReturnRule::Ground: return "ground";
    case ReturnRule::Sky: return "sky";
    case ReturnRule::Vehicle: return "vehicle";
    case ReturnRule::count: break;
  }
  return "?";
}

namespace {


const float* need_channel(const PolarGridMap& pgm, const char* name) {
  if (!pgm.has_channel(name))
    throw input_error("polar grid map", std::string("channel ") + name, "required by the return target");
  return pgm.channel(name);
}

}  // namespace

double estimate_sensor_height(const PolarGridMap& pgm) {
  const auto& el = pgm.layout().elevations_rad;
  if (el.empty()) return 0;
  const double cut = std::min(el.back() / 2, -3.0 * kPi / 180);
  const float* range = pgm.channel("range");
  const float* mask = pgm.channel("mask");
  const float* height = pgm.has_channel("height") ? pgm.channel("height") : nullptr;
  std::vector<double> depth;  // -z of the lower beams' returns
  for (int r = 0; r < pgm.rows(); ++r) {
    if (el[r] > cut) continue;
    for (int c = 0; c < pgm.cols(); ++c) {
      const std::size_t i = static_cast<std::size_t>(r) * pgm.cols() + c;
      if (mask[i] < 0.5f) continue;
      const double z = height ? height[i] : range[i] * std::sin(el[r]);
      if (-z >= 0.2 && -z < 5.0) depth.push_back(-z);
    }
  }
  if (depth.size() < 50) return 0;
  constexpr double bin = 0.02;
  std::vector<int> hist(static_cast<std::size_t>((5.0 - 0.2) / bin) + 1, 0);
  for (double d : depth) ++hist[static_cast<std::size_t>((d - 0.2) / bin)];
  // The ground of a real scan spreads over tens of cm (sensor pitch, road crown, kerbs): the
  // mode of counts within +-10 cm, not of single bins, so two near-equal peaks do not flip it.
  std::vector<int> window(hist.size(), 0);
  for (std::size_t k = 0; k < hist.size(); ++k)
    for (std::size_t q = k >= 5 ? k - 5 : 0; q <= std::min(hist.size() - 1, k + 5); ++q) window[k] += hist[q];
  const std::size_t wide = static_cast<std::size_t>(std::max_element(window.begin(), window.end()) - window.begin());
  // Then the densest single bin near it: a flat ground is one bin, at the window's edge.
  const std::size_t lo = wide >= 5 ? wide - 5 : 0, hi = std::min(hist.size() - 1, wide + 5);
  const std::size_t mode = static_cast<std::size_t>(std::max_element(hist.begin() + lo, hist.begin() + hi + 1) - hist.begin());
  const double centre = 0.2 + (mode + 0.5) * bin;
  std::vector<double> near;
  for (double d : depth)
    if (std::abs(d - centre) <= 0.1) near.push_back(d);
  std::nth_element(near.begin(), near.begin() + near.size() / 2, near.end());
  return near[near.size() / 2];
}

namespace {

// The channels and geometry every rule reads.
struct Scan {
  const float* range;
  const float* mask;
  const float* cls;
  int H, W;
  const std::vector<double>& el;
  bool has(std::size_t i) const { return mask[i] >= 0.5f; }
  std::size_t at(int r, int c) const { return static_cast<std::size_t>(r) * W + c; }
};

// Every cell Sky, then each measured cell a Return; the measured ranges for the reach.
std::vector<float> label_measured(const Scan& s, std::size_t n, ReturnTarget& t) {
  t.rows = s.H;
  t.cols = s.W;
  t.label.assign(n, ReturnLabel::Sky);
  t.rule.assign(n, ReturnRule::Sky);
  t.range.assign(n, 0.f);
  t.class_id.assign(n, 0);
  std::vector<float> ranges;
  for (std::size_t i = 0; i < n; ++i)
    if (s.has(i)) {
      t.label[i] = ReturnLabel::Return;
      t.rule[i] = ReturnRule::Measured;
      t.range[i] = s.range[i];
      t.class_id[i] = static_cast<int>(s.cls[i]);
      ranges.push_back(s.range[i]);
    }
  t.returns = static_cast<long long>(ranges.size());
  if (ranges.empty()) throw input_error("polar grid map", "mask", "no returns: the return target needs a measured scan");
  return ranges;
}

// Reach and sensor height (given or estimated), then the ground range of each row
// (0 = the beam does not meet the ground within reach).
std::vector<double> ground_ranges(const PolarGridMap& pgm, const Scan& s, std::vector<float>& ranges,
                                  const ReturnTargetOptions& o, ReturnTarget& t) {
  t.reach_m = o.reach_m;
  if (t.reach_m <= 0) {
    const auto k = std::min(ranges.size() - 1, static_cast<std::size_t>(o.reach_quantile * ranges.size()));
    std::nth_element(ranges.begin(), ranges.begin() + k, ranges.end());
    t.reach_m = ranges[k];
  }
  t.sensor_height_m = o.sensor_height_m > 0 ? o.sensor_height_m : estimate_sensor_height(pgm);
  if (!(t.sensor_height_m > 0))
    throw input_error("polar grid map", "sensor height",
                      "too few returns on the lower beams to estimate it; give it (--sensor-height)");
  const double ground_reach = o.ground_reach_share * t.reach_m;
  std::vector<double> ground(s.H, 0.0);
  for (int r = 0; r < s.H; ++r)
    if (s.el[r] < 0) {
      const double g = t.sensor_height_m / std::sin(-s.el[r]);
      if (g <= ground_reach) ground[r] = g;
    }
  return ground;
}

// Rule 0: long empty runs on near-ground rows are the own vehicle (columns wrap around).
void rule_vehicle(const Scan& s, const std::vector<double>& ground, const ReturnTargetOptions& o, ReturnTarget& t) {
  const int H = s.H, W = s.W;
  for (int r = 0; r < H && o.vehicle_run > 0 && o.vehicle_run <= W; ++r) {
    if (!(ground[r] > 0 && ground[r] <= o.vehicle_ground_m)) continue;
    const std::size_t row0 = s.at(r, 0);
    int start = 0;  // a column with a return to start from, so no run is cut by the wrap
    while (start < W && !s.has(row0 + start)) ++start;
    if (start == W) continue;  // an empty row: nothing to tell a vehicle from
    for (int k = 1, run = 0; k <= W; ++k) {
      const int c = (start + k) % W;
      if (k < W && !s.has(row0 + c)) {
        ++run;
        continue;
      }
      if (run >= o.vehicle_run)
        for (int q = 1; q <= run; ++q) t.rule[row0 + (c - q + W) % W] = ReturnRule::Vehicle;
      run = 0;
    }
  }
}

// Rule 1: gaps in a row between two returns at similar range (columns wrap around).
void rule_row_gap(const Scan& s, const ReturnTargetOptions& o, ReturnTarget& t) {
  const int H = s.H, W = s.W;
  for (int r = 0; r < H; ++r) {
    const std::size_t row0 = s.at(r, 0);
    std::vector<int> left(W, -1), right(W, -1);  // nearest return column (unwrapped offset) or -1
    int last = -1;
    for (int k = 0; k < 2 * W; ++k) {
      const int c = k % W;
      if (s.has(row0 + c)) last = k;
      else if (k >= W && last >= 0 && k - last <= o.row_gap + 1) left[c] = k - last;
    }
    last = -1;
    for (int k = 2 * W - 1; k >= 0; --k) {
      const int c = k % W;
      if (s.has(row0 + c)) last = k;
      else if (k < W && last >= 0 && last - k <= o.row_gap + 1) right[c] = last - k;
    }
    for (int c = 0; c < W; ++c) {
      const std::size_t i = row0 + c;
      if (s.has(i) || t.rule[i] == ReturnRule::Vehicle || left[c] < 0 || right[c] < 0 || left[c] + right[c] > o.row_gap + 1)
        continue;
      const std::size_t a = row0 + (c - left[c] + W) % W, b = row0 + (c + right[c]) % W;
      const double ra = s.range[a], rb = s.range[b];
      if (std::abs(ra - rb) > o.similar_range * std::min(ra, rb)) continue;
      const double w = static_cast<double>(left[c]) / (left[c] + right[c]);
      t.label[i] = ReturnLabel::Drop;
      t.rule[i] = ReturnRule::RowGap;
      t.range[i] = static_cast<float>(ra + w * (rb - ra));
      t.class_id[i] = static_cast<int>(s.cls[left[c] <= right[c] ? a : b]);
    }
  }
}

// Ground class of cell (r, c): the nearest return below in the column, else the one above.
int ground_class(const Scan& s, int r, int c, int above) {
  for (int q = r + 1; q < s.H; ++q)
    if (s.has(s.at(q, c))) return static_cast<int>(s.cls[s.at(q, c)]);
  return above >= 0 ? static_cast<int>(s.cls[s.at(above, c)]) : 0;
}

// Rule 2: the surface above reaches down to an empty cell of column c unless the next return below lies
// beyond it (the beams in between passed under it: an overhang).
bool below_return(const Scan& s, int c, int above, int below, double similar_range) {
  if (above < 0) return false;
  if (below < 0) return true;
  const std::size_t a = s.at(above, c), b = s.at(below, c);
  return s.range[b] * std::cos(s.el[below]) <= (1 + similar_range) * s.range[a] * std::cos(s.el[above]);
}

// Rule 2 (below a return), else rule 3 (ground), for the cells rules 0 and 1 left as Sky, column
// by column.
void rules_below_return_and_ground(const Scan& s, const std::vector<double>& ground, const ReturnTargetOptions& o,
                                   ReturnTarget& t) {
  const int H = s.H, W = s.W;
  std::vector<int> below(H);  // nearest row below with a return, -1 if none
  for (int c = 0; c < W; ++c) {
    for (int r = H - 1, next = -1; r >= 0; --r) {
      below[r] = next;
      if (s.has(s.at(r, c))) next = r;
    }
    int above = -1;  // nearest row above with a return
    for (int r = 0; r < H; ++r) {
      const std::size_t i = s.at(r, c);
      if (s.has(i)) {
        above = r;
        continue;
      }
      if (t.label[i] != ReturnLabel::Sky || t.rule[i] == ReturnRule::Vehicle) continue;
      if (below_return(s, c, above, below[r], o.similar_range)) {
        const std::size_t a = s.at(above, c);
        const double horizontal = s.range[a] * std::cos(s.el[above]);
        const double wall = horizontal / std::cos(s.el[r]);
        const bool surface_first = ground[r] <= 0 || wall <= ground[r];
        t.label[i] = ReturnLabel::Drop;
        t.rule[i] = ReturnRule::BelowReturn;
        t.range[i] = static_cast<float>(surface_first ? wall : ground[r]);
        t.class_id[i] = surface_first ? static_cast<int>(s.cls[a]) : ground_class(s, r, c, above);
      } else if (ground[r] > 0) {
        t.label[i] = ReturnLabel::Drop;
        t.rule[i] = ReturnRule::Ground;
        t.range[i] = static_cast<float>(ground[r]);
        t.class_id[i] = ground_class(s, r, c, above);
      }
    }
  }
}

// Rule 4 is what is left: cells no rule labelled stay Sky. Count each rule's cells.
void count_rules(ReturnTarget& t) {
  for (std::size_t i = 0; i < t.label.size(); ++i) {
    ++t.by_rule[static_cast<int>(t.rule[i])];
    if (t.label[i] == ReturnLabel::Drop) ++t.drops;
    else if (t.label[i] == ReturnLabel::Sky) ++t.sky;
  }
}

}  // namespace

ReturnTarget return_target(const PolarGridMap& pgm, const ReturnTargetOptions& o) {
  const Scan s{need_channel(pgm, "range"), need_channel(pgm, "mask"), need_channel(pgm, "class"),
               pgm.rows(), pgm.cols(), pgm.layout().elevations_rad};
  ReturnTarget t;
  std::vector<float> ranges = label_measured(s, pgm.cells(), t);
  const std::vector<double> ground = ground_ranges(pgm, s, ranges, o, t);
  rule_vehicle(s, ground, o, t);
  rule_row_gap(s, o, t);
  rules_below_return_and_ground(s, ground, o, t);
  count_rules(t);
  return t;
}

}  // namespace lidarsim::pgm
