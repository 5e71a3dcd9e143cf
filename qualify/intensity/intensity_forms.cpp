// Candidate forms of the intensity loop, scored on the pooled held-out residual.
//
// A sensor effect can add to the intensity (an offset per laser) or scale it (a gain per laser, a
// dirty window): the residual of a scaled effect grows with the prediction, so its mean per bin
// can be near 0 where a base model has already learnt part of it (a UNet learns each row's mean
// level from the training columns), and an additive table of it then explains nothing. So every
// feature is tried as an additive table, a gain table (measured ~ g * base per bin), an affine
// table (residual ~ a + s (base - mean base) per bin: a gain about the mean level, what is left of
// a gain once the level is learnt), and as an additive or gain window. A laser's gain may also
// depend on range (its own fall-off): the features that index lasers are tried as a range slope
// per bin too (measured ~ base * exp(a + s ln range) per bin). Each form is judged by the refit it
// implies: the held-out error of base + its correction.
#include <algorithm>
#include <cmath>
#include <map>

#include "data/baselines.h"
#include "qualify/intensity/intensity_internal.h"
#include "qualify/windows.h"

namespace lidarsim::qualify::intensity_detail {

std::string form_name(Form f, bool per_row) {
  switch (f) {
    case Form::Table: return per_row ? "per-beam table" : "binned table";
    case Form::Window: return "window";
    case Form::GainTable: return per_row ? "per-beam gain" : "binned gain";
    case Form::WindowGain: return "window gain";
    case Form::AffineTable: return per_row ? "per-row affine" : "binned affine";
    case Form::RangeSlope: return per_row ? "per-beam range slope" : "binned range slope";
  }
  return "?";
}

bool additive(Form f) { return f == Form::Table || f == Form::Window; }

bool range_interaction_applies(const std::string& feature) { return feature == "beam_row" || feature == "elevation"; }

bool scenery_feature(const std::string& feature) { return feature == "height"; }

namespace {
// ln of the range, held at 1 m below it (the housing region, where no fall-off law holds).
double log_range(double range_m) { return std::log(std::max(range_m, 1.0)); }
}  // namespace

const char* decision_name(Decision d) {
  switch (d) {
    case Decision::Added: return "added";
    case Decision::NotAdded: return "not added";
    case Decision::Tried: return "tried";
    case Decision::NotTried: return "not tried";
    case Decision::NotRanked: return "not ranked";
    case Decision::CannotDecide: return "the data cannot decide";
  }
  return "?";
}

double FittedForm::delta_in(int b, double base, double range_m) const {
  switch (form) {
    case Form::Table:
    case Form::Window: return table.value[b];
    case Form::GainTable:
    case Form::WindowGain: return base * (table.value[b] - 1);
    case Form::AffineTable: return table.value[b] + slope[b] * (base - centre);
    case Form::RangeSlope: return base * (std::exp(table.value[b] + slope[b] * (log_range(range_m) - centre)) - 1);
  }
  return 0;
}

namespace {

// Per bin, ridge least squares of r on (1, base - centre): the offset shrunk like fit_table's mean
// (n / (n + shrink)), the slope by `shrink` cells' worth of the bin's spread of the base. On the
// cells idx; bin[i]: cell i's bin in `edges` (nullptr: one bin).
FittedForm fit_affine(const std::vector<double>& edges, const int* bin, const std::vector<double>& r,
                      const std::vector<double>& base, const std::vector<size_t>& idx, double shrink = 5) {
  FittedForm f;
  f.form = Form::AffineTable;
  f.table.edges = edges;
  const size_t nb = edges.size() + 1;
  double sum = 0;  // mean_of the cells' base
  for (size_t i : idx) sum += base[i];
  f.centre = idx.empty() ? 0 : sum / idx.size();
  std::vector<double> n(nb, 0), sd(nb, 0), sdd(nb, 0), sr(nb, 0), srd(nb, 0);
  for (size_t i : idx) {
    const int b = bin ? bin[i] : 0;
    const double d = base[i] - f.centre;
    n[b] += 1, sd[b] += d, sdd[b] += d * d, sr[b] += r[i], srd[b] += r[i] * d;
  }
  f.table.value.assign(nb, 0.0);
  f.table.count.assign(nb, 0);
  f.slope.assign(nb, 0.0);
  for (size_t b = 0; b < nb; ++b) {
    f.table.count[b] = static_cast<long>(n[b]);
    if (n[b] == 0) continue;
    const double la = shrink, ls = shrink * sdd[b] / n[b];
    const double a11 = n[b] + la, a12 = sd[b], a22 = sdd[b] + ls;
    const double det = a11 * a22 - a12 * a12;
    if (!(det > 1e-12)) {
      f.table.value[b] = sr[b] / a11;
      continue;
    }
    f.table.value[b] = (a22 * sr[b] - a12 * srd[b]) / det;
    f.slope[b] = (a11 * srd[b] - a12 * sr[b]) / det;
  }
  return f;
}

// Per bin, measured ~ base * exp(a + s d), d = ln range - centre, by penalised Gauss-Newton from
// a = s = 0 (gain 1): the penalty is `shrink` cells' worth of the bin's own curvature, as
// fit_affine's, so a thin bin stays near gain 1 and a bin without range spread keeps slope ~0.
// Least squares on the intensity itself (not on log(measured / base), which noisy returns near 0
// would make undefined or heavy-tailed).
FittedForm fit_range_slope(const std::vector<double>& edges, const std::vector<double>& x,
                           const std::vector<double>& measured, const std::vector<double>& base,
                           const std::vector<double>& range, double shrink = 5) {
  FittedForm f;
  f.form = Form::RangeSlope;
  f.table.edges = edges;
  const size_t nb = edges.size() + 1, n = x.size();
  std::vector<int> bin(n);
  std::vector<double> d(n);
  for (size_t i = 0; i < n; ++i) d[i] = log_range(range[i]), f.centre += d[i] / std::max<size_t>(1, n);
  std::vector<double> cnt(nb, 0), pa(nb, 0), ps(nb, 0);  // counts; penalties on a and s
  for (size_t i = 0; i < n; ++i) {
    d[i] -= f.centre, bin[i] = f.table.bin(x[i]);
    cnt[bin[i]] += 1, pa[bin[i]] += base[i] * base[i], ps[bin[i]] += base[i] * base[i] * d[i] * d[i];
  }
  for (size_t b = 0; b < nb; ++b)
    if (cnt[b] > 0) pa[b] *= shrink / cnt[b], ps[b] *= shrink / cnt[b];
  f.table.value.assign(nb, 0.0);
  f.table.count.assign(nb, 0);
  for (size_t b = 0; b < nb; ++b) f.table.count[b] = static_cast<long>(cnt[b]);
  f.slope.assign(nb, 0.0);
  for (int it = 0; it < 8; ++it) {
    // Normal equations per bin: [Jaa Jas; Jas Jss] step = [ga; gs] (penalty included).
    std::vector<std::array<double, 5>> ne(nb, std::array<double, 5>{});
    for (size_t i = 0; i < n; ++i) {
      const int b = bin[i];
      const double g = base[i] * std::exp(f.table.value[b] + f.slope[b] * d[i]), e = measured[i] - g;
      auto& q = ne[b];
      q[0] += g * g, q[1] += g * g * d[i], q[2] += g * g * d[i] * d[i], q[3] += g * e, q[4] += g * e * d[i];
    }
    for (size_t b = 0; b < nb; ++b) {
      const auto& q = ne[b];
      const double a11 = q[0] + pa[b], a12 = q[1], a22 = q[2] + ps[b];
      const double r1 = q[3] - pa[b] * f.table.value[b], r2 = q[4] - ps[b] * f.slope[b];
      const double det = a11 * a22 - a12 * a12;
      if (!(det > 1e-18)) continue;
      // Steps and values bounded: a gain beyond e^+-3 or a fall-off steeper than range^+-3 is no
      // laser's, and the bound keeps a poorly conditioned bin from diverging.
      f.table.value[b] = std::clamp(f.table.value[b] + (a22 * r1 - a12 * r2) / det, -3.0, 3.0);
      f.slope[b] = std::clamp(f.slope[b] + (a11 * r2 - a12 * r1) / det, -3.0, 3.0);
    }
  }
  return f;
}

bool is_window(Form f) { return f == Form::Window || f == Form::WindowGain; }

// The form without the feature (one bin): a constant, a global gain, a global gain and offset. A
// form's score is what the feature adds to it, so that a base model's global miscalibration (its
// residual growing with its prediction everywhere) does not pass for an effect of every feature.
Form one_bin(Form f) {
  if (f == Form::AffineTable || f == Form::RangeSlope) return f;
  return additive(f) ? Form::Table : Form::GainTable;
}

}  // namespace

namespace {

// The cells a form is fitted on, picked once for a form and its one-bin version. Gains are fitted
// to the winsorised measurement (base + clamped residual), as the tables are.
struct FitCells {
  std::vector<double> x, r, base, measured, range;  // range: RangeSlope only
};

// What `form` reads: the additive window x and r only; RangeSlope the range too.
FitCells pick_cells(Form form, const std::vector<double>& x, const std::vector<double>& rc,
                    const std::vector<double>& base, const std::vector<double>& range, const std::vector<size_t>& idx) {
  FitCells c{pick(x, idx), pick(rc, idx), {}, {}, {}};
  if (form == Form::Window) return c;
  c.base = pick(base, idx);
  c.measured.resize(c.x.size());
  for (size_t i = 0; i < c.measured.size(); ++i) c.measured[i] = c.base[i] + c.r[i];
  if (form == Form::RangeSlope) c.range = pick(range, idx);
  return c;
}

FittedForm fit_picked(Form form, const std::vector<double>& edges, const std::vector<double>& fine, const FitCells& c) {
  FittedForm f;
  f.form = form;
  switch (form) {
    case Form::Table: f.table = fit_table(edges, c.x, c.r); break;
    case Form::Window: f.table = fit_window(fine, c.x, c.r); break;
    case Form::GainTable: f.table = fit_gain_table(edges, c.x, c.measured, c.base); break;
    case Form::WindowGain: {
      const BinnedTable w = fit_window(fine, c.x, c.r);
      if (!w.value.empty()) f.table = fit_window_gain(w, c.x, c.measured, c.base);
      break;
    }
    case Form::AffineTable: {
      const BinnedTable t{edges, {}, {}};
      std::vector<int> bin(c.x.size());
      std::vector<size_t> all(c.x.size());
      for (size_t i = 0; i < c.x.size(); ++i) bin[i] = t.bin(c.x[i]), all[i] = i;
      f = fit_affine(edges, bin.data(), c.r, c.base, all);
      break;
    }
    case Form::RangeSlope: f = fit_range_slope(edges, c.x, c.measured, c.base, c.range); break;
  }
  return f;
}

// The tables (additive, gain, affine) on the cells idx of the pooled arrays, with each cell's bin
// in `edges` found once for every form and group (bin[i]; nullptr: one bin): fit_table's and
// fit_gain_table's sums and shrinkage, in the same order, without copying the cells out.
bool binned(Form f) { return f == Form::Table || f == Form::GainTable || f == Form::AffineTable; }

FittedForm fit_binned(Form form, const std::vector<double>& edges, const int* bin, const std::vector<double>& r,
                      const std::vector<double>& base, const std::vector<size_t>& idx, double shrink = 5) {
  if (form == Form::AffineTable) return fit_affine(edges, bin, r, base, idx, shrink);
  FittedForm f;
  f.form = form;
  BinnedTable& t = f.table;
  t.edges = edges;
  const size_t nb = edges.size() + 1;
  std::vector<double> xy(nb, 0.0), xx(nb, 0.0);  // Table: xy = sum r
  t.count.assign(nb, 0);
  if (form == Form::Table) {
    for (size_t i : idx) {
      const int b = bin ? bin[i] : 0;
      xy[b] += r[i];
      ++t.count[b];
    }
    t.value.assign(nb, 0.0);
    for (size_t b = 0; b < nb; ++b)
      if (t.count[b] > 0) t.value[b] = xy[b] / (t.count[b] + shrink);
    return f;
  }
  for (size_t i : idx) {  // GainTable: measured = base + clamped residual
    const int b = bin ? bin[i] : 0;
    const double m = base[i] + r[i];
    xy[b] += m * base[i];
    xx[b] += base[i] * base[i];
    ++t.count[b];
  }
  t.value.assign(nb, 1.0);
  for (size_t b = 0; b < nb; ++b) {
    if (t.count[b] == 0 || xx[b] <= 0) continue;
    const double prior = shrink * xx[b] / t.count[b];  // shrink pseudo-cells at gain 1
    t.value[b] = (xy[b] + prior) / (xx[b] + prior);
  }
  return f;
}

// The bin of x in f's table when `edge_bin` is x's bin in the edges the form was fitted on: a
// table's edges are those; a window's are its own two, (lo, hi), binned as BinnedTable::bin does.
int form_bin(const FittedForm& f, double x, int edge_bin) {
  if (!is_window(f.form)) return edge_bin;
  return x < f.table.edges[1] ? (x < f.table.edges[0] ? 0 : 1) : 2;
}

// Bootstrap blocks numbered densely in increasing block order (as a map keyed by block visits them).
std::vector<int> block_ids(const Pooled& p, int& blocks) {
  std::map<long, int> id;
  for (size_t i = 0; i < p.size(); ++i)
    if (i == 0 || p.block[i] != p.block[i - 1]) id.emplace(p.block[i], 0);
  blocks = 0;
  for (auto& [b, i] : id) i = blocks++;
  std::vector<int> out(p.size());
  long last = 0;
  int last_id = -1;
  for (size_t i = 0; i < p.size(); ++i) {
    if (last_id < 0 || p.block[i] != last) last = p.block[i], last_id = id.at(last);
    out[i] = last_id;
  }
  return out;
}

}  // namespace

FittedForm fit_form(Form form, const std::vector<double>& edges, const std::vector<double>& fine,
                    const std::vector<double>& x, const std::vector<double>& rc, const std::vector<double>& base,
                    const std::vector<double>& range, const std::vector<size_t>& idx) {
  return fit_picked(form, edges, fine, pick_cells(form, x, rc, base, range, idx));
}

std::vector<double> lookup_with_range_slope(const IntensityCells& c, size_t feature, const std::vector<double>& edges) {
  std::vector<size_t> fit;
  for (size_t i = 0; i < c.size(); ++i)
    if (!c.held_out[i]) fit.push_back(i);
  const std::vector<double>&x = c.feature[feature], &range = c.feature[0];
  const std::vector<double> fallback = lookup_prediction(c);  // keys without fit cells: class, then global mean
  // The lookup's key (class x range bin) of every cell, numbered densely once: class index x
  // kRangeBins + range bin.
  std::map<int, int> class_index;
  for (size_t i = 0; i < c.size(); ++i)
    if (i == 0 || c.cls[i] != c.cls[i - 1]) class_index.emplace(c.cls[i], 0);
  int classes = 0;
  for (auto& [cls, k] : class_index) k = classes++;
  std::vector<int> key(c.size());
  for (size_t i = 0; i < c.size(); ++i) key[i] = class_index.at(c.cls[i]) * data::kRangeBins + data::range_bin(range[i]);
  std::vector<std::array<double, 2>> t;  // key -> (sum m g, sum g^2)
  std::vector<double> level = fallback, gain(c.size(), 1.0), resid(c.size(), 0.0);
  // Alternating least squares from the plain lookup: levels given the gains, then the slopes given
  // the levels. Each half-step lowers the fit cells' squared error; four rounds settle it (the
  // levels move by < 1e-4 after the third on the planted scans).
  for (int round = 0; round < 4; ++round) {
    t.assign(classes * data::kRangeBins, {0.0, 0.0});  // a key without fit cells keeps sum g^2 = 0
    for (size_t i : fit) {
      auto& e = t[key[i]];
      e[0] += c.measured[i] * gain[i], e[1] += gain[i] * gain[i];
    }
    for (size_t i = 0; i < c.size(); ++i) {
      const auto& e = t[key[i]];
      level[i] = e[1] > 0 ? e[0] / e[1] : fallback[i];
    }
    std::vector<double> r;
    for (size_t i : fit) r.push_back(c.measured[i] - level[i]);
    const Winsor w = winsor_limits(r);
    for (size_t i = 0; i < c.size(); ++i) resid[i] = w(c.measured[i] - level[i]);
    const FittedForm f = fit_form(Form::RangeSlope, edges, {}, x, resid, level, range, fit);
    for (size_t i = 0; i < c.size(); ++i) gain[i] = 1 + f.delta(x[i], 1.0, range[i]);
  }
  std::vector<double> out(c.size());
  for (size_t i = 0; i < c.size(); ++i) out[i] = level[i] * gain[i];
  return out;
}

FormScore score_form(Form form, const Pooled& p, size_t feature, const std::vector<double>& edges,
                     const std::vector<double>& fine, const std::vector<double>& rc, bool keep_corrected,
                     const std::vector<Fold>* folds, const CrossFit* cross) {
  const std::vector<double>& x = p.feature[feature];
  const std::vector<double>& range = p.feature[0];  // kIntensityFeatures starts with range
  FormScore s;
  std::vector<size_t> all(p.size());
  for (size_t i = 0; i < all.size(); ++i) all[i] = i;
  // Each cell's bin, found once: in `edges` (the tables) or in `fine` (the windows' fine bins).
  const BinnedTable bins{is_window(form) ? fine : edges, {}, {}};
  std::vector<int> bin(p.size());
  for (size_t i = 0; i < p.size(); ++i) bin[i] = bins.bin(x[i]);
  // `form` or its one-bin version (single: one bin, no edges) on the cells idx.
  auto fit = [&](Form fm, bool single, const std::vector<size_t>& idx) {
    if (binned(fm)) return fit_binned(fm, single ? std::vector<double>{} : edges, single ? nullptr : bin.data(), rc, p.base, idx);
    const FitCells cells = pick_cells(fm, x, rc, p.base, range, idx);
    return single ? fit_picked(fm, {}, {}, cells) : fit_picked(fm, edges, fine, cells);
  };
  s.shown = fit(form, false, all);
  if (!s.shown.ok()) return s;
  s.corrected = p.base;
  int nblocks = 0;
  const std::vector<int> block = block_ids(p, nblocks);
  std::vector<std::array<double, 3>> blocks(nblocks, {0.0, 0.0, 0.0});  // block -> (sse, sst, n)
  std::vector<char> seen(nblocks, 0);
  double abs_sum = 0;
  const CrossFit cf = cross ? *cross : cross_fit_for(p, kIntensityFeatures[feature]);
  const bool joint = folds && joint_azimuth_gain(p, kIntensityFeatures[feature], form);
  if (joint) {
    // Its one-bin version is a gain common to every azimuth, which the refitted levels absorb:
    // the plain lookup, d0 = 0.
    s.corrected = lookup_with_azimuth_gain(*folds, p, form, edges, fine);
    for (size_t i = 0; i < p.size(); ++i) {
      const double d = s.corrected[i] - p.base[i];
      auto& b = blocks[block[i]];
      seen[block[i]] = 1;
      b[0] += (rc[i] - d) * (rc[i] - d), b[1] += rc[i] * rc[i], b[2] += 1;
    }
  }
  // Crossed groups (2 x class + row block) fit on the other row block only: its cells listed once.
  std::vector<size_t> in_block[2];
  if (cf.crossed && !joint)
    for (size_t i = 0; i < p.size(); ++i) in_block[cf.group[i] % 2].push_back(i);
  for (int g = 0; g < (joint ? 0 : cf.groups); ++g) {
    std::vector<size_t> fit_cells, apply;
    if (cf.crossed) {
      for (size_t i : in_block[g % 2])
        if (cf.group[i] == g) apply.push_back(i);
      for (size_t i : in_block[1 - g % 2])
        if (cf.fits(g, cf.group[i])) fit_cells.push_back(i);
    } else {
      for (size_t i = 0; i < p.size(); ++i) {
        if (cf.group[i] == g) apply.push_back(i);
        else if (cf.fits(g, cf.group[i])) fit_cells.push_back(i);
      }
    }
    if (fit_cells.empty() || apply.empty()) continue;
    const FittedForm f = fit(form, false, fit_cells);
    const FittedForm one = fit(one_bin(form), true, fit_cells);
    // Fit cells per fine bin: a window's level is known only where its fine bins had fit cells
    // (its edges may span azimuths another group holds out).
    std::vector<long> fine_count(fine.size() + 1, 0);
    if (is_window(form))
      for (size_t i : fit_cells) ++fine_count[bin[i]];
    for (size_t i : apply) {
      // A bin without fit cells (a range of the feature only this group has: azimuths another
      // fold holds out) has no level of its own; the one-bin form stands in for it. (The one-bin
      // form's table has no edges: every x is in its bin 0.)
      const double d0 = one.delta_in(0, p.base[i], range[i]);
      const bool known = f.ok() && (is_window(form) ? fine_count[bin[i]] > 0 : f.table.count[bin[i]] > 0);
      const double d = known ? f.delta_in(form_bin(f, x[i], bin[i]), p.base[i], range[i]) : d0;
      s.corrected[i] = p.base[i] + d;
      auto& b = blocks[block[i]];
      seen[block[i]] = 1;
      b[0] += (rc[i] - d) * (rc[i] - d);
      b[1] += (rc[i] - d0) * (rc[i] - d0);
      b[2] += 1;
    }
  }
  std::array<double, 3> total{0, 0, 0};
  BlockSums bl;
  for (int k = 0; k < nblocks; ++k) {
    if (!seen[k]) continue;
    bl.push_back(blocks[k]);
    for (size_t q = 0; q < 3; ++q) total[q] += blocks[k][q];
  }
  s.r2 = r2_of_sums(total);
  s.interval = block_bootstrap_interval(bl, r2_of_sums, 1000);
  for (size_t i = 0; i < p.size(); ++i) abs_sum += std::abs(s.corrected[i] - p.measured[i]);
  s.mae_after = p.size() ? abs_sum / p.size() : 0;
  if (!keep_corrected) s.corrected = {};
  if (form == Form::Window || form == Form::WindowGain) {
    s.effect = s.shown.table.value[1] - s.shown.table.value[0];
  } else {
    double sq = 0;
    for (size_t i = 0; i < p.size(); ++i) sq += std::pow(s.shown.delta_in(bin[i], p.base[i], range[i]), 2);
    s.effect = p.size() ? std::sqrt(sq / p.size()) : 0;
  }
  return s;
}

}  // namespace lidarsim::qualify::intensity_detail
