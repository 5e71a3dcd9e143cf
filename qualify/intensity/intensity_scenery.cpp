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

size_t azimuth_feature() {
  return std::find(kIntensityFeatures.begin(), kIntensityFeatures.end(), "azimuth") - kIntensityFeatures.begin();
}

// The folds' cells as dense arrays, built once per lookup_with_azimuth_gain call: each group's
// alternations pass over every fold's fit cells, a few hundred passes per call, and a pass that
// reads arrays costs a small share of one that looks up a map and bins every azimuth anew. The
// lookup's key (class x range bin) is numbered class index x kRangeBins + range bin.
struct FoldIndex {
  std::vector<int> fit_key, fit_fine, fit_edge;  // per fit cell of the fold, in cell order
  std::vector<double> fit_measured, fit_azimuth;
  std::vector<int> held_key;  // per held-out cell, in Fold::held order (= the fold's pooled cells)
};
struct JointIndex {
  int keys = 0;  // every key is < keys
  std::vector<FoldIndex> folds;
  std::vector<int> pooled_key, pooled_fine, pooled_edge;  // per pooled cell
};

// `fine_bins`: the window search's fine bins; `edge_bins`: the gain table's bins.
JointIndex joint_index(const std::vector<Fold>& folds, const Pooled& p, const BinnedTable& fine_bins,
                       const BinnedTable& edge_bins) {
  const size_t iaz = azimuth_feature();
  std::map<int, int> class_index;
  for (const Fold& f : folds)
    for (int c : f.cells.cls) class_index.emplace(c, 0);
  for (int c : p.cls) class_index.emplace(c, 0);
  int classes = 0;
  for (auto& [c, i] : class_index) i = classes++;
  JointIndex ix;
  ix.keys = classes * data::kRangeBins;
  auto key = [&](int cls, double range) { return class_index.at(cls) * data::kRangeBins + data::range_bin(range); };
  for (const Fold& fold : folds) {
    const IntensityCells& c = fold.cells;
    FoldIndex f;
    for (size_t i = 0; i < c.size(); ++i)
      if (!c.held_out[i]) {
        const double az = c.feature[iaz][i];
        f.fit_key.push_back(key(c.cls[i], c.feature[0][i]));
        f.fit_fine.push_back(fine_bins.bin(az));
        f.fit_edge.push_back(edge_bins.bin(az));
        f.fit_measured.push_back(c.measured[i]);
        f.fit_azimuth.push_back(az);
      }
    for (size_t i : fold.held) f.held_key.push_back(key(c.cls[i], c.feature[0][i]));
    ix.folds.push_back(std::move(f));
  }
  for (size_t i = 0; i < p.size(); ++i) {
    ix.pooled_key.push_back(key(p.cls[i], p.feature[0][i]));
    ix.pooled_fine.push_back(fine_bins.bin(p.feature[iaz][i]));
    ix.pooled_edge.push_back(edge_bins.bin(p.feature[iaz][i]));
  }
  return ix;
}

// Per fold, the lookup's levels refitted with the gain G divided out: sum m G / sum G^2 per key
// over the fold's fit cells; per pooled cell (any group) its level, the plain lookup where its
// key has no fit cells. gain(fold, j): G of the fold's j-th fit cell.
template <class Gain>
std::vector<double> levels_with_gain(const JointIndex& ix, const Pooled& p, Gain gain) {
  std::vector<double> level = p.lookup;
  std::vector<std::array<double, 2>> t;  // key -> (sum m G, sum G^2)
  for (size_t k = 0; k < ix.folds.size(); ++k) {
    const FoldIndex& f = ix.folds[k];
    t.assign(ix.keys, {0.0, 0.0});
    // Neighbouring cells mostly share a key: its sums stay in registers over a run of them (the
    // same additions in the same order as through t).
    int run = -1;
    double s0 = 0, s1 = 0;
    for (size_t j = 0; j < f.fit_key.size(); ++j) {
      if (f.fit_key[j] != run) {
        if (run >= 0) t[run] = {s0, s1};
        run = f.fit_key[j], s0 = t[run][0], s1 = t[run][1];
      }
      const double G = gain(k, j);
      s0 += f.fit_measured[j] * G, s1 += G * G;
    }
    if (run >= 0) t[run] = {s0, s1};
    for (size_t j = 0; j < f.held_key.size(); ++j) {
      const auto& e = t[f.held_key[j]];
      if (e[1] > 0) level[p.offset[k] + j] = e[0] / e[1];
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
//
// The folds' side does not depend on `fit`: WindowSums holds it for every group of a call. A slot
// is a (fold, key) with fit cells, numbered in order of first appearance over the folds' fit
// cells; sums are prefix sums over the fine bins, stored [bin * slots + slot], so that a window
// reads three contiguous rows.
struct WindowSums {
  size_t nb = 0, slots = 0;
  std::vector<int> slot;  // [fold * keys + key] -> slot, -1: no fit cells
  std::vector<double> fit_m, fit_n;
};

WindowSums window_sums(const JointIndex& ix, size_t nb) {
  WindowSums s;
  s.nb = nb;
  s.slot.assign(ix.folds.size() * ix.keys, -1);
  for (size_t k = 0; k < ix.folds.size(); ++k)
    for (int key : ix.folds[k].fit_key) {
      int& sl = s.slot[k * ix.keys + key];
      if (sl < 0) sl = static_cast<int>(s.slots++);
    }
  const size_t S = s.slots;
  s.fit_m.assign((nb + 1) * S, 0.0), s.fit_n.assign((nb + 1) * S, 0.0);
  for (size_t k = 0; k < ix.folds.size(); ++k) {
    const FoldIndex& f = ix.folds[k];
    for (size_t j = 0; j < f.fit_key.size(); ++j) {
      const size_t at = (f.fit_fine[j] + 1) * S + s.slot[k * ix.keys + f.fit_key[j]];
      s.fit_m[at] += f.fit_measured[j], s.fit_n[at] += 1;
    }
  }
  for (auto* v : {&s.fit_m, &s.fit_n})
    for (size_t b = 1; b <= nb; ++b)
      for (size_t q = 0; q < S; ++q) (*v)[b * S + q] += (*v)[(b - 1) * S + q];
  return s;
}

struct WindowFit {
  size_t a = 0, b = 0;  // fine bins [a, b] inside
  double g_in = 1, g_out = 1, sse = 1e300;
};

// Per slot, the sums inside [a, b] and outside it, of the folds' fit cells (f*) and of `fit` (h*).
// held_m, held_n: `fit`'s prefix sums, laid out as WindowSums'. One scratch serves every group of a
// call (allocated once: a few MB, which fresh pages per group would cost more to clear).
struct WindowScratch {
  std::vector<double> fmi, fni, fmo, fno, hmi, hni, hmo, hno, level, held_m, held_n;
  explicit WindowScratch(const WindowSums& ws) {
    for (auto* v : {&fmi, &fni, &fmo, &fno, &hmi, &hni, &hmo, &hno, &level}) v->assign(ws.slots, 0.0);
    held_m.assign((ws.nb + 1) * ws.slots, 0.0), held_n.assign((ws.nb + 1) * ws.slots, 0.0);
  }
};

WindowFit fit_joint_window(const WindowSums& ws, size_t a, size_t b, WindowScratch& w) {
  WindowFit out;
  out.a = a, out.b = b;
  const size_t S = ws.slots, nb = ws.nb;
  auto split = [&](const std::vector<double>& pre, std::vector<double>& in, std::vector<double>& outside) {
    const double *lo = &pre[a * S], *hi = &pre[(b + 1) * S], *all = &pre[nb * S];
    for (size_t k = 0; k < S; ++k) in[k] = hi[k] - lo[k], outside[k] = all[k] - in[k];
  };
  split(ws.fit_m, w.fmi, w.fmo), split(ws.fit_n, w.fni, w.fno);
  split(w.held_m, w.hmi, w.hmo), split(w.held_n, w.hni, w.hno);
  double g_in = 1, g_out = 1;
  const double *__restrict fmi = w.fmi.data(), *__restrict fmo = w.fmo.data();
  const double *__restrict fni = w.fni.data(), *__restrict fno = w.fno.data();
  double* __restrict level = w.level.data();
  for (int round = 0; round < kJointRounds; ++round) {
    // Every slot has fit cells (fni + fno >= 1), so with both squared gains > 0 every den is > 0:
    // that case is a loop without a branch, which runs on whole vectors.
    const double a = g_in * g_in, c = g_out * g_out;
    if (a > 0 && c > 0) {
      for (size_t k = 0; k < S; ++k)
        level[k] = (g_in * fmi[k] + g_out * fmo[k]) / (a * fni[k] + c * fno[k]);
    } else {
      for (size_t k = 0; k < S; ++k) {
        const double den = a * fni[k] + c * fno[k];
        level[k] = den > 0 ? (g_in * fmi[k] + g_out * fmo[k]) / den : 0;
      }
    }
    double xy_in = 0, xx_in = 0, xy_out = 0, xx_out = 0;
    for (size_t k = 0; k < S; ++k) {
      const double l = w.level[k];
      xy_in += l * w.hmi[k], xx_in += l * l * w.hni[k];
      xy_out += l * w.hmo[k], xx_out += l * l * w.hno[k];
    }
    if (!(xx_in > 0 && xx_out > 0)) return out;
    g_in = xy_in / xx_in, g_out = xy_out / xx_out;
  }
  double sse = 0;  // minus the constant sum of m^2
  for (size_t k = 0; k < S; ++k) {
    const double l = w.level[k];
    sse += -2 * l * (g_in * w.hmi[k] + g_out * w.hmo[k]) + l * l * (g_in * g_in * w.hni[k] + g_out * g_out * w.hno[k]);
  }
  out.g_in = g_in, out.g_out = g_out, out.sse = sse;
  return out;
}

// joint_window_gain over the folds' sums `ws`; `fine` the fine bins' edges.
FittedForm joint_window(const WindowSums& ws, const JointIndex& ix, const Pooled& p, const std::vector<size_t>& fit,
                        const std::vector<double>& fine, WindowScratch& scratch) {
  const size_t nb = ws.nb, S = ws.slots;
  std::vector<double>&held_m = scratch.held_m, &held_n = scratch.held_n;
  std::fill(held_m.begin(), held_m.end(), 0.0), std::fill(held_n.begin(), held_n.end(), 0.0);
  // Keys without fit cells have no level (the plain lookup falls back to the class mean): left out
  // of the search, as they carry nothing of the window's contrast.
  long held = 0;
  for (size_t i : fit) {
    const int sl = ws.slot[p.fold[i] * ix.keys + ix.pooled_key[i]];
    if (sl < 0) continue;
    const size_t at = (ix.pooled_fine[i] + 1) * S + sl;
    held_m[at] += p.measured[i], held_n[at] += 1, ++held;
  }
  for (auto* v : {&held_m, &held_n})
    for (size_t b = 1; b <= nb; ++b)
      for (size_t q = 0; q < S; ++q) (*v)[b * S + q] += (*v)[(b - 1) * S + q];
  std::vector<double> held_total(nb + 1, 0.0);  // prefix counts of `fit` cells over the fine bins
  for (size_t q = 0; q < S; ++q)
    for (size_t b = 0; b <= nb; ++b) held_total[b] += held_n[b * S + q];
  // A window needs cells inside and outside: kWindowMinShare of the fit cells on either side.
  auto valid = [&](size_t a, size_t b) {
    const double n_in = held_total[b + 1] - held_total[a];
    return n_in >= kWindowMinShare * held && held - n_in >= kWindowMinShare * held;
  };
  WindowFit best;
  auto consider = [&](size_t a, size_t b) {
    if (a > b || b >= nb || !valid(a, b)) return;
    const WindowFit w = fit_joint_window(ws, a, b, scratch);
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
  const double n_in = held_total[best.b + 1] - held_total[best.a];
  f.table.count = {long(held - n_in), long(n_in), 0};
  return f;
}

// fit_form's GainTable and its one-bin version (fit_gain_table's sums and shrinkage) on the cells
// `fit`, binned by `bin`, measured = level + clamped residual as fit_form takes it: the gain G per
// bin, the one-bin gain where the fit cells have none in a bin (as score_form).
std::vector<double> gain_per_bin(const std::vector<size_t>& fit, const std::vector<int>& bin, size_t bins,
                                 const Pooled& p, const std::vector<double>& level, double shrink = 5) {
  std::vector<double> r;
  r.reserve(fit.size());
  for (size_t i : fit) r.push_back(p.measured[i] - level[i]);
  const Winsor w = winsor_limits(r);
  std::vector<double> xy(bins + 1, 0.0), xx(bins + 1, 0.0);  // the last: every fit cell (one bin)
  std::vector<long> count(bins + 1, 0);
  for (size_t i : fit) {
    const double bs = level[i], ms = bs + w(p.measured[i] - level[i]);
    for (size_t b : {size_t(bin[i]), bins}) xy[b] += ms * bs, xx[b] += bs * bs, ++count[b];
  }
  std::vector<double> value(bins + 1, 1.0), gain(bins);
  for (size_t b = 0; b <= bins; ++b) {
    if (count[b] == 0 || xx[b] <= 0) continue;
    const double prior = shrink * xx[b] / count[b];
    value[b] = (xy[b] + prior) / (xx[b] + prior);
  }
  // 1 + delta(az, base 1): 1 + 1 x (value - 1).
  for (size_t b = 0; b < bins; ++b) gain[b] = 1 + 1.0 * ((count[b] > 0 ? value[b] : value[bins]) - 1);
  return gain;
}

}  // namespace

FittedForm joint_window_gain(const std::vector<Fold>& folds, const Pooled& p, const std::vector<size_t>& fit,
                             const std::vector<double>& fine) {
  BinnedTable fine_bins;
  fine_bins.edges = fine;
  const JointIndex ix = joint_index(folds, p, fine_bins, BinnedTable{});
  const WindowSums ws = window_sums(ix, fine.size() + 1);
  WindowScratch scratch(ws);
  return joint_window(ws, ix, p, fit, fine, scratch);
}

std::vector<double> lookup_with_azimuth_gain(const std::vector<Fold>& folds, const Pooled& p, Form form,
                                             const std::vector<double>& edges, const std::vector<double>& fine) {
  (void)fine;  // the gain table's bins are `edges`; the window's, equal-count bins of its own
  const CrossFit& cf = p.azimuth_scenery;
  const std::vector<double>& x = p.feature[azimuth_feature()];
  std::vector<double> out = p.lookup;
  BinnedTable window_bins, edge_bins;
  if (form == Form::WindowGain) {
    std::vector<double> sorted = x;  // equal-count edges depend on the values only: sorted is the cheap case
    std::sort(sorted.begin(), sorted.end());
    window_bins.edges = equal_count_edges(sorted, kWindowFineBins);
  }
  edge_bins.edges = edges;
  const JointIndex ix = joint_index(folds, p, window_bins, edge_bins);
  const WindowSums ws = form == Form::WindowGain ? window_sums(ix, window_bins.edges.size() + 1) : WindowSums{};
  WindowScratch scratch(ws);
  for (int g = 0; g < cf.groups; ++g) {
    std::vector<size_t> fit;
    for (size_t i = 0; i < p.size(); ++i)
      if (cf.group[i] != g && cf.fits(g, cf.group[i])) fit.push_back(i);
    if (fit.empty()) continue;
    std::vector<double> level = p.lookup;
    if (form == Form::WindowGain) {
      // The window and its edges fitted jointly with the levels (joint_window_gain). The groups
      // share their columns, so the window's edges hold for every group's cells (a gap of the
      // fit cells inside the window is still inside it).
      const FittedForm f = joint_window(ws, ix, p, fit, window_bins.edges, scratch);
      if (!f.ok()) continue;
      // 1 + f.delta(az, 1, 0), with the window's bin as BinnedTable::bin finds it on its two edges.
      const double lo = f.table.edges[0], hi = f.table.edges[1];
      double gain_of[3];
      for (int b = 0; b < 3; ++b) gain_of[b] = 1 + 1.0 * (f.table.value[b] - 1);
      auto window_gain = [&](double az) { return gain_of[az < hi ? (az < lo ? 0 : 1) : 2]; };
      level = levels_with_gain(ix, p, [&](size_t k, size_t j) { return window_gain(ix.folds[k].fit_azimuth[j]); });
      for (size_t i = 0; i < p.size(); ++i)
        if (cf.group[i] == g) out[i] = window_gain(x[i]) * level[i];
      continue;
    }
    // Alternating least squares: the gain fitted on the fit cells (other classes, other rows) over the levels
    // refitted with the previous gain (this group's own gain: no level of a fit cell comes from
    // a gain fitted on this group's cells), then the levels with the new gain.
    std::vector<double> gain;
    for (int round = 0; round < kJointRounds; ++round) {
      gain = gain_per_bin(fit, ix.pooled_edge, edges.size() + 1, p, level);
      level = levels_with_gain(ix, p, [&](size_t k, size_t j) { return gain[ix.folds[k].fit_edge[j]]; });
    }
    for (size_t i = 0; i < p.size(); ++i)
      if (cf.group[i] == g) out[i] = gain[ix.pooled_edge[i]] * level[i];
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
