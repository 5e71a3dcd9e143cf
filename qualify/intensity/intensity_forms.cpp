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

double FittedForm::delta(double x, double base, double range_m) const {
  const int b = table.bin(x);
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
// (n / (n + shrink)), the slope by `shrink` cells' worth of the bin's spread of the base.
FittedForm fit_affine(const std::vector<double>& edges, const std::vector<double>& x, const std::vector<double>& r,
                      const std::vector<double>& base, double shrink = 5) {
  FittedForm f;
  f.form = Form::AffineTable;
  f.table.edges = edges;
  const size_t nb = edges.size() + 1;
  f.centre = base.empty() ? 0 : mean_of(base);
  std::vector<double> n(nb, 0), sd(nb, 0), sdd(nb, 0), sr(nb, 0), srd(nb, 0);
  for (size_t i = 0; i < x.size(); ++i) {
    const int b = f.table.bin(x[i]);
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

FittedForm fit_form(Form form, const std::vector<double>& edges, const std::vector<double>& fine,
                    const std::vector<double>& x, const std::vector<double>& rc, const std::vector<double>& base,
                    const std::vector<double>& range, const std::vector<size_t>& idx) {
  const std::vector<double> xs = pick(x, idx), rs = pick(rc, idx), bs = pick(base, idx);
  // Gains are fitted to the winsorised measurement (base + clamped residual), as the tables are.
  std::vector<double> ms(xs.size());
  for (size_t i = 0; i < ms.size(); ++i) ms[i] = bs[i] + rs[i];
  FittedForm f;
  f.form = form;
  switch (form) {
    case Form::Table: f.table = fit_table(edges, xs, rs); break;
    case Form::Window: f.table = fit_window(fine, xs, rs); break;
    case Form::GainTable: f.table = fit_gain_table(edges, xs, ms, bs); break;
    case Form::WindowGain: {
      const BinnedTable w = fit_window(fine, xs, rs);
      if (!w.value.empty()) f.table = fit_window_gain(w, xs, ms, bs);
      break;
    }
    case Form::AffineTable: f = fit_affine(edges, xs, rs, bs); break;
    case Form::RangeSlope: f = fit_range_slope(edges, xs, ms, bs, pick(range, idx)); break;
  }
  return f;
}

std::vector<double> lookup_with_range_slope(const IntensityCells& c, size_t feature, const std::vector<double>& edges) {
  std::vector<size_t> fit;
  for (size_t i = 0; i < c.size(); ++i)
    if (!c.held_out[i]) fit.push_back(i);
  const std::vector<double>&x = c.feature[feature], &range = c.feature[0];
  const std::vector<double> fallback = lookup_prediction(c);  // keys without fit cells: class, then global mean
  auto key = [&](size_t i) { return long(c.cls[i]) * 1000 + data::range_bin(range[i]); };
  std::vector<double> level = fallback, gain(c.size(), 1.0), resid(c.size(), 0.0);
  // Alternating least squares from the plain lookup: levels given the gains, then the slopes given
  // the levels. Each half-step lowers the fit cells' squared error; four rounds settle it (the
  // levels move by < 1e-4 after the third on the planted scans).
  for (int round = 0; round < 4; ++round) {
    std::map<long, std::array<double, 2>> t;  // key -> (sum m g, sum g^2)
    for (size_t i : fit) {
      auto& e = t[key(i)];
      e[0] += c.measured[i] * gain[i], e[1] += gain[i] * gain[i];
    }
    for (size_t i = 0; i < c.size(); ++i) {
      const auto it = t.find(key(i));
      level[i] = it != t.end() && it->second[1] > 0 ? it->second[0] / it->second[1] : fallback[i];
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
  s.shown = fit_form(form, edges, fine, x, rc, p.base, range, all);
  if (!s.shown.ok()) return s;
  s.corrected = p.base;
  std::map<long, std::array<double, 3>> blocks;  // block -> (sse, sst, n)
  double abs_sum = 0;
  const CrossFit cf = cross ? *cross : cross_fit_for(p, kIntensityFeatures[feature]);
  const bool joint = folds && joint_azimuth_gain(p, kIntensityFeatures[feature], form);
  if (joint) {
    // Its one-bin version is a gain common to every azimuth, which the refitted levels absorb:
    // the plain lookup, d0 = 0.
    s.corrected = lookup_with_azimuth_gain(*folds, p, form, edges, fine);
    for (size_t i = 0; i < p.size(); ++i) {
      const double d = s.corrected[i] - p.base[i];
      auto& b = blocks[p.block[i]];
      b[0] += (rc[i] - d) * (rc[i] - d), b[1] += rc[i] * rc[i], b[2] += 1;
    }
  }
  for (int g = 0; g < (joint ? 0 : cf.groups); ++g) {
    std::vector<size_t> fit, apply;
    for (size_t i = 0; i < p.size(); ++i) {
      if (cf.group[i] == g) apply.push_back(i);
      else if (cf.fits(g, cf.group[i])) fit.push_back(i);
    }
    if (fit.empty() || apply.empty()) continue;
    const FittedForm f = fit_form(form, edges, fine, x, rc, p.base, range, fit);
    const FittedForm one = fit_form(one_bin(form), {}, {}, x, rc, p.base, range, fit);
    // Fit cells per fine bin: a window's level is known only where its fine bins had fit cells
    // (its edges may span azimuths another group holds out).
    BinnedTable fine_bins;
    fine_bins.edges = fine;
    std::vector<long> fine_count(fine.size() + 1, 0);
    for (size_t i : fit) ++fine_count[fine_bins.bin(x[i])];
    for (size_t i : apply) {
      // A bin without fit cells (a range of the feature only this group has: azimuths another
      // fold holds out) has no level of its own; the one-bin form stands in for it.
      const double d0 = one.delta(x[i], p.base[i], range[i]);
      const bool known = f.ok() && (is_window(form) ? fine_count[fine_bins.bin(x[i])] > 0
                                                    : f.table.count[f.table.bin(x[i])] > 0);
      const double d = known ? f.delta(x[i], p.base[i], range[i]) : d0;
      s.corrected[i] = p.base[i] + d;
      auto& b = blocks[p.block[i]];
      b[0] += (rc[i] - d) * (rc[i] - d);
      b[1] += (rc[i] - d0) * (rc[i] - d0);
      b[2] += 1;
    }
  }
  std::array<double, 3> total{0, 0, 0};
  BlockSums bl;
  for (const auto& [k, v] : blocks) {
    bl.push_back(v);
    for (size_t q = 0; q < 3; ++q) total[q] += v[q];
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
    for (size_t i = 0; i < p.size(); ++i) sq += std::pow(s.shown.delta(x[i], p.base[i], range[i]), 2);
    s.effect = p.size() ? std::sqrt(sq / p.size()) : 0;
  }
  return s;
}

}  // namespace lidarsim::qualify::intensity_detail
