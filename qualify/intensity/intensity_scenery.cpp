// The azimuth cross-fit of the intensity loop on scans of one scenery (intensity_internal.h,
// scenery_cross_fit).
//
// Why classes x row blocks, crossed. A gain of the sensor over a window of azimuth multiplies
// every return in those columns, whatever it hits and at whichever laser; the base's error on the
// scenery there (a wall darker than its class's mean, a wet patch of road) belongs to one object:
// one class, a band of rows. A form fitted on the other classes alone would still carry a dark
// object that spans classes in one band of rows (a wet road and its kerb); fitted on the other
// row block alone, it would carry one tall object of one class (a building over every row of its
// columns). Fitted on the cells that share neither the class nor the row block, only what is
// common to the columns across both carries over, as a sensor's gain does.
//
// Why each class against all the others, not two fixed groups of classes: one scan shows
// different classes on different sides (grass and trees on one, road and buildings on the other),
// so two groups of about equal size are often each seen on one side only, and a window there had
// no cells of the opposite group (RELLIS-3D: 61 % of the cells covered, windows over the trees
// scored R^2 <= 0.06). Against every other class, only azimuths where one class is all there is
// stay uncovered, and those the data cannot decide: a sensor's window there is a dark object.
#include <algorithm>
#include <cstdio>
#include <map>

#include "data/baselines.h"
#include "qualify/intensity/intensity_internal.h"
#include "qualify/windows.h"

namespace lidarsim::qualify::intensity_detail {

namespace {

std::string pct(double share) {
  char b[32];
  std::snprintf(b, sizeof b, "%.0f %%", 100 * share);
  return b;
}

// One group per class, numbered by class id (deterministic).
std::map<int, int> class_index(const std::vector<int>& cls) {
  std::map<int, int> index;
  for (int c : cls) index.emplace(c, 0);
  int k = 0;
  for (auto& [c, i] : index) i = k++;
  return index;
}

// The row splitting the cells into two halves (rows below it: block 0).
int median_row(std::vector<int> rows) {
  if (rows.empty()) return 0;
  std::nth_element(rows.begin(), rows.begin() + rows.size() / 2, rows.end());
  return rows[rows.size() / 2];
}

}  // namespace

void scenery_cross_fit(Pooled& p, const std::string& columns_reason) {
  p.azimuth_scenery = {};
  const size_t iaz = std::find(kIntensityFeatures.begin(), kIntensityFeatures.end(), "azimuth") - kIntensityFeatures.begin();
  const std::map<int, int> by_class = class_index(p.cls);
  const int classes = static_cast<int>(by_class.size());
  int split_row = median_row(p.row);
  // All cells on one side of the median (few rows with returns): the block boundary above it.
  if (std::none_of(p.row.begin(), p.row.end(), [&](int r) { return r < split_row; })) ++split_row;
  std::vector<int> group(p.size());
  long block[2] = {0, 0};
  for (size_t i = 0; i < p.size(); ++i) {
    const int rb = p.row[i] >= split_row ? 1 : 0;
    group[i] = 2 * by_class.at(p.cls[i]) + rb;
    ++block[rb];
  }
  const bool two_classes = classes >= 2;
  const bool two_blocks = block[0] > 0 && block[1] > 0;
  auto undecided = [&](const std::string& why) {
    p.azimuth_undecided = columns_reason + "; across classes x row blocks in the same columns: " + why;
  };
  if (!two_classes || !two_blocks) {
    undecided(!two_classes ? "1 class" : "1 block of rows");
    return;
  }
  // Coverage: a cell's azimuth form is fitted on the cells of the other classes in the other row
  // block at its azimuth; where there are (almost) none, the form falls back to no effect, and
  // where that holds for most cells the score says nothing either way.
  BinnedTable fine;
  fine.edges = equal_count_edges(p.feature[iaz], kSceneryFineBins);
  std::vector<std::vector<long>> n(fine.edges.size() + 1, std::vector<long>(2 * classes, 0));
  for (size_t i = 0; i < p.size(); ++i) ++n[fine.bin(p.feature[iaz][i])][group[i]];
  long covered = 0;
  for (const auto& bin : n) {
    long in_block[2] = {0, 0};
    for (int g = 0; g < 2 * classes; ++g) in_block[g % 2] += bin[g];
    for (int g = 0; g < 2 * classes; ++g) {
      const int other = g ^ 1;  // the same class in the other row block
      if (in_block[other % 2] - bin[other] >= kSceneryMinCellsPerBin) covered += bin[g];
    }
  }
  const double coverage = p.size() ? static_cast<double>(covered) / p.size() : 0;
  if (coverage < kSceneryMinCoverage) {
    undecided("only " + pct(coverage) + " of the held-out cells have at least " +
              std::to_string(kSceneryMinCellsPerBin) + " cells of the other classes in the other rows at their " +
              "azimuth (" + pct(kSceneryMinCoverage) + " needed)");
    return;
  }
  p.azimuth_undecided.clear();
  CrossFit& c = p.azimuth_scenery;
  c.group = std::move(group), c.groups = 2 * classes, c.crossed = true;
  c.by = "classes x row blocks in the same columns (" + std::to_string(classes) +
         " classes, rows split at row " + std::to_string(split_row) +
         "; each class in each block fitted on the other classes in the other block, " + pct(coverage) + " of the cells covered), because " +
         columns_reason;
}

namespace {

// Per fold, the lookup's levels refitted with the gain G divided out: sum m G / sum G^2 per key
// over the fold's fit cells; per pooled cell (any group) its level, the plain lookup where its
// key has no fit cells.
template <class Gain>
std::vector<double> levels_with_gain(const std::vector<Fold>& folds, const Pooled& p, Gain gain, size_t iaz) {
  std::vector<double> level = p.lookup;
  for (size_t k = 0; k < folds.size(); ++k) {
    const IntensityCells& c = folds[k].cells;
    auto key = [&](size_t i) { return long(c.cls[i]) * 1000 + data::range_bin(c.feature[0][i]); };
    std::map<long, std::array<double, 2>> t;  // key -> (sum m G, sum G^2)
    for (size_t i = 0; i < c.size(); ++i)
      if (!c.held_out[i]) {
        const double G = gain(c.feature[iaz][i]);
        auto& e = t[key(i)];
        e[0] += c.measured[i] * G, e[1] += G * G;
      }
    for (size_t j = 0; j < folds[k].held.size(); ++j) {
      const auto it = t.find(key(folds[k].held[j]));
      if (it != t.end() && it->second[1] > 0) level[p.offset[k] + j] = it->second[0] / it->second[1];
    }
  }
  return level;
}

// The window of a gain over azimuth with its edges fitted jointly with the lookup's levels, on
// the cells `fit` (pooled held-out cells) with each fold's levels from its own fit cells.
//
// Why not the additive window over the plain lookup's residual: the plain lookup's levels (class x
// range bin) hold the window's gain in proportion to each key's share of cells inside it, and on
// one scan a key is often one object, inside or outside. The residual left is then the gain of
// the keys that span the edges, and the best additive window over it can lie elsewhere (RELLIS: a
// 1.85 x gain over 112 deg found at 227-293 deg). Here every window of the fine bins is fitted as
// the model itself: level(fold, key) x gain (g_in inside, g_out outside), the levels refitted on
// the folds' fit cells given the gains and the gains on `fit` given the levels (3 alternations),
// and the window with the lowest squared error on `fit` wins. Prefix sums over the fine bins per
// (fold, key) make a window O(keys). Coarse search on every kWindowCoarse-th edge, then each edge
// refined over the finer edges within one coarse bin.
struct KeyBins {
  std::vector<std::vector<double>> fit_m, fit_n, held_m, held_n;  // per (fold, key): prefix sums over fine bins
};

struct WindowFit {
  size_t a = 0, b = 0;  // fine bins [a, b] inside
  double g_in = 1, g_out = 1, sse = 1e300;
};

WindowFit fit_joint_window(const KeyBins& kb, size_t nb, size_t a, size_t b) {
  WindowFit w;
  w.a = a, w.b = b;
  const size_t keys = kb.fit_m.size();
  std::vector<double> level(keys, 0.0);
  double g_in = 1, g_out = 1;
  auto in = [&](const std::vector<double>& pre) { return pre[b + 1] - pre[a]; };
  for (int round = 0; round < kJointRounds; ++round) {
    for (size_t k = 0; k < keys; ++k) {
      const double mi = in(kb.fit_m[k]), ni = in(kb.fit_n[k]);
      const double mo = kb.fit_m[k][nb] - mi, no = kb.fit_n[k][nb] - ni;
      const double den = g_in * g_in * ni + g_out * g_out * no;
      level[k] = den > 0 ? (g_in * mi + g_out * mo) / den : 0;
    }
    double xy_in = 0, xx_in = 0, xy_out = 0, xx_out = 0;
    for (size_t k = 0; k < keys; ++k) {
      const double mi = in(kb.held_m[k]), ni = in(kb.held_n[k]);
      xy_in += level[k] * mi, xx_in += level[k] * level[k] * ni;
      xy_out += level[k] * (kb.held_m[k][nb] - mi), xx_out += level[k] * level[k] * (kb.held_n[k][nb] - ni);
    }
    if (!(xx_in > 0 && xx_out > 0)) return w;
    g_in = xy_in / xx_in, g_out = xy_out / xx_out;
  }
  double sse = 0;  // minus the constant sum of m^2
  for (size_t k = 0; k < keys; ++k) {
    const double mi = in(kb.held_m[k]), ni = in(kb.held_n[k]);
    const double mo = kb.held_m[k][nb] - mi, no = kb.held_n[k][nb] - ni;
    sse += -2 * level[k] * (g_in * mi + g_out * mo) + level[k] * level[k] * (g_in * g_in * ni + g_out * g_out * no);
  }
  w.g_in = g_in, w.g_out = g_out, w.sse = sse;
  return w;
}

}  // namespace

FittedForm joint_window_gain(const std::vector<Fold>& folds, const Pooled& p, const std::vector<size_t>& fit,
                             const std::vector<double>& fine) {
  const size_t iaz = std::find(kIntensityFeatures.begin(), kIntensityFeatures.end(), "azimuth") - kIntensityFeatures.begin();
  BinnedTable bins;
  bins.edges = fine;
  const size_t nb = fine.size() + 1;
  std::map<long, size_t> id;  // fold * 1e6 + class * 1000 + range bin -> key
  auto key_of = [&](size_t fold, int cls, double range) {
    return long(fold) * 1000000 + long(cls) * 1000 + data::range_bin(range);
  };
  KeyBins kb;
  auto slot = [&](long key) {
    const auto [it, fresh] = id.emplace(key, kb.fit_m.size());
    if (fresh)
      for (auto* v : {&kb.fit_m, &kb.fit_n, &kb.held_m, &kb.held_n}) v->push_back(std::vector<double>(nb + 1, 0.0));
    return it->second;
  };
  // Keys without fit cells have no level (the plain lookup falls back to the class mean): left out
  // of the search, as they carry nothing of the window's contrast.
  for (size_t k = 0; k < folds.size(); ++k) {
    const IntensityCells& c = folds[k].cells;
    for (size_t i = 0; i < c.size(); ++i)
      if (!c.held_out[i]) {
        const size_t s = slot(key_of(k, c.cls[i], c.feature[0][i]));
        const int b = bins.bin(c.feature[iaz][i]);
        kb.fit_m[s][b + 1] += c.measured[i], kb.fit_n[s][b + 1] += 1;
      }
  }
  long held = 0;
  for (size_t i : fit) {
    const auto it = id.find(key_of(p.fold[i], p.cls[i], p.feature[0][i]));
    if (it == id.end()) continue;
    const int b = bins.bin(p.feature[iaz][i]);
    kb.held_m[it->second][b + 1] += p.measured[i], kb.held_n[it->second][b + 1] += 1, ++held;
  }
  for (auto* v : {&kb.fit_m, &kb.fit_n, &kb.held_m, &kb.held_n})
    for (auto& pre : *v)
      for (size_t b = 1; b <= nb; ++b) pre[b] += pre[b - 1];
  std::vector<double> held_n(nb + 1, 0.0);  // prefix counts of `fit` cells over the fine bins
  for (const auto& pre : kb.held_n)
    for (size_t b = 0; b <= nb; ++b) held_n[b] += pre[b];
  // A window needs cells inside and outside: kWindowMinShare of the fit cells on either side.
  auto valid = [&](size_t a, size_t b) {
    const double n_in = held_n[b + 1] - held_n[a];
    return n_in >= kWindowMinShare * held && held - n_in >= kWindowMinShare * held;
  };
  WindowFit best;
  auto consider = [&](size_t a, size_t b) {
    if (a > b || b >= nb || !valid(a, b)) return;
    const WindowFit w = fit_joint_window(kb, nb, a, b);
    if (w.sse < best.sse) best = w;
  };
  const size_t coarse = kWindowCoarse;
  for (size_t a = 0; a < nb; a += coarse)
    for (size_t b = a + coarse - 1; b < nb + coarse - 1; b += coarse) consider(a, std::min(b, nb - 1));
  if (best.sse >= 1e300) return {};
  const WindowFit c = best;
  for (size_t a = c.a >= coarse ? c.a - coarse : 0; a <= c.a + coarse; ++a)
    for (size_t b = c.b >= coarse ? c.b - coarse : 0; b <= std::min(nb - 1, c.b + coarse); ++b) consider(a, b);
  FittedForm f;
  f.form = Form::WindowGain;
  f.table.edges = {best.a == 0 ? -1e300 : fine[best.a - 1], best.b + 1 >= nb ? 1e300 : fine[best.b]};
  // As gains about the outside level (which the refitted levels hold): outside 1, inside g_in / g_out.
  f.table.value = {1.0, best.g_in / best.g_out, 1.0};
  f.table.count = {long(held - (held_n[best.b + 1] - held_n[best.a])), long(held_n[best.b + 1] - held_n[best.a]), 0};
  return f;
}

std::vector<double> lookup_with_azimuth_gain(const std::vector<Fold>& folds, const Pooled& p, Form form,
                                             const std::vector<double>& edges, const std::vector<double>& fine) {
  const CrossFit& cf = p.azimuth_scenery;
  const size_t iaz = std::find(kIntensityFeatures.begin(), kIntensityFeatures.end(), "azimuth") - kIntensityFeatures.begin();
  const std::vector<double>&x = p.feature[iaz], &range = p.feature[0];
  std::vector<double> out = p.lookup;
  BinnedTable fine_bins;
  fine_bins.edges = fine;
  const std::vector<double> window_fine = equal_count_edges(x, kWindowFineBins);
  for (int g = 0; g < cf.groups; ++g) {
    std::vector<size_t> fit;
    for (size_t i = 0; i < p.size(); ++i)
      if (cf.group[i] != g && cf.fits(g, cf.group[i])) fit.push_back(i);
    if (fit.empty()) continue;
    std::vector<long> fine_count(fine.size() + 1, 0);
    for (size_t i : fit) ++fine_count[fine_bins.bin(x[i])];
    FittedForm f, one;
    // As score_form: where the fit cells have none at an azimuth, the one-bin gain.
    auto gain = [&](double az) {
      if (!one.ok()) return 1.0;
      const bool known = f.ok() && (form == Form::WindowGain ? fine_count[fine_bins.bin(az)] > 0
                                                             : f.table.count[f.table.bin(az)] > 0);
      return 1 + (known ? f : one).delta(az, 1.0, 0.0);
    };
    // Alternating least squares: the gain fitted on the fit cells (other classes, other rows) over the levels
    // refitted with the previous gain (this group's own gain: no level of a fit cell comes from
    // a gain fitted on this group's cells), then the levels with the new gain.
    std::vector<double> level = p.lookup;
    if (form == Form::WindowGain) {
      // The window and its edges fitted jointly with the levels (joint_window_gain). The groups
      // share their columns, so the window's edges hold for every group's cells (a gap of the
      // fit cells inside the window is still inside it).
      f = joint_window_gain(folds, p, fit, window_fine);
      if (!f.ok()) continue;
      auto window_gain = [&](double az) { return 1 + f.delta(az, 1.0, 0.0); };
      level = levels_with_gain(folds, p, window_gain, iaz);
      for (size_t i = 0; i < p.size(); ++i)
        if (cf.group[i] == g) out[i] = window_gain(x[i]) * level[i];
      continue;
    }
    for (int round = 0; round < kJointRounds; ++round) {
      std::vector<double> r(p.size(), 0.0), rf;
      for (size_t i : fit) rf.push_back(p.measured[i] - level[i]);
      const Winsor w = winsor_limits(rf);
      for (size_t i : fit) r[i] = w(p.measured[i] - level[i]);
      f = fit_form(form, edges, fine, x, r, level, range, fit);
      one = fit_form(Form::GainTable, {}, {}, x, r, level, range, fit);
      level = levels_with_gain(folds, p, gain, iaz);
    }
    for (size_t i = 0; i < p.size(); ++i)
      if (cf.group[i] == g) out[i] = gain(x[i]) * level[i];
  }
  return out;
}

void check_across_scenery(Candidate& k, const Pooled& p, size_t feature, const std::vector<double>& edges,
                          const std::vector<double>& fine, const std::vector<double>& rc) {
  if (!scenery_feature(k.feature) || !p.azimuth_scenery.crossed) return;
  const FormScore crossed = score_form(k.form, p, feature, edges, fine, rc, false, nullptr, &p.azimuth_scenery);
  k.column_r2 = k.score.r2, k.scenery_checked = true;
  if (crossed.r2 < k.score.r2) k.score = crossed;
}

bool joint_azimuth_gain(const Pooled& p, const std::string& feature, Form form) {
  return (form == Form::GainTable || form == Form::WindowGain) && cross_fit_for(p, feature).crossed;
}

CrossFit cross_fit_for(const Pooled& p, const std::string& feature) {
  if (feature == "azimuth" && p.azimuth_scenery.groups > 0) return p.azimuth_scenery;
  return {p.group, p.groups, false, p.group_by};
}

}  // namespace lidarsim::qualify::intensity_detail
