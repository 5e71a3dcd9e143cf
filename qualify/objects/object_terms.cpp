#include "qualify/objects/object_terms.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>

namespace lidarsim::qualify::obj {

double Refit::operator()(int cls, int rb, double x) const {
  if (relative >= 0) throw std::logic_error("object loop: a relative term evaluated without the object's size");
  return at(cls, rb, x, 1.0);
}

std::vector<double> relative_values(const Split& s, const Refit& f) {
  return f.relative >= 0 ? s.column(f.relative) : std::vector<double>(s.r.size(), 1.0);
}

ClassTables fit_class_tables(const std::vector<double>& x, const std::vector<double>& r, const std::vector<int>& cls,
                             int bins) {
  ClassTables t;
  t.pooled = fit_binned_mean(x, r, bins);
  for (int c = 0; c < kObjectClassCount; ++c) {
    std::vector<double> xc, rc;
    for (size_t i = 0; i < x.size(); ++i)
      if (cls[i] == c) xc.push_back(x[i]), rc.push_back(r[i]);
    if (xc.size() >= 200) t.per_class[c] = fit_binned_mean(xc, rc, bins), t.own[c] = true;
  }
  return t;
}

namespace {
// The (class, range bin) cell offsets: each cell's mean residual after the table, for cells with
// at least 20 samples (fewer: no offset).
void fit_cell_offsets(Refit& f, const std::vector<double>& x, const std::vector<double>& r, const std::vector<int>& cls,
                      const std::vector<int>& rb) {
  std::map<std::pair<int, int>, std::pair<double, long>> acc;
  for (size_t i = 0; i < r.size(); ++i) {
    auto& a = acc[{cls[i], rb[i]}];
    // Detection (cell_prior > 0): the base's cells are already its shrunk fit to these records, so
    // a cell takes back only the table's mean over it, shrunk alike; a zero table is the base.
    a.first += f.cell_prior > 0 ? -f.table(cls[i], x[i]) : r[i] - f.table(cls[i], x[i]);
    ++a.second;
  }
  f.d.clear();
  for (const auto& [k, a] : acc)
    if (a.second >= 20) f.d[k] = a.first / (a.second + f.cell_prior);
}

// Alternates the term's per-class fit (fit_term) and the base's cell offsets, four passes.
template <class FitTerm>
Refit backfit_with(const std::vector<double>& x, const std::vector<double>& r, const std::vector<int>& cls,
                   const std::vector<int>& rb, double cell_prior, const FitTerm& fit_term) {
  Refit f;
  f.cell_prior = cell_prior;
  std::vector<double> y(r.size());
  for (int pass = 0; pass < 4; ++pass) {
    for (size_t i = 0; i < r.size(); ++i) {
      const auto it = f.d.find({cls[i], rb[i]});
      y[i] = r[i] - (it == f.d.end() ? 0.0 : it->second);
    }
    f.table = fit_term(y);
    fit_cell_offsets(f, x, r, cls, rb);
  }
  return f;
}

}  // namespace

Refit backfit(const std::vector<double>& x, const std::vector<double>& r, const std::vector<int>& cls,
              const std::vector<int>& rb, int bins, double cell_prior) {
  return backfit_with(x, r, cls, rb, cell_prior,
                      [&](const std::vector<double>& y) { return fit_class_tables(x, y, cls, bins); });
}

BinnedTable fit_window(const std::vector<double>& x, const std::vector<double>& y, int fine_bins, long min_side) {
  const BinnedTable fine = fit_binned_mean(x, y, fine_bins, 0);
  const int K = static_cast<int>(fine.value.size());
  std::vector<double> S(K + 1, 0.0);
  std::vector<long> N(K + 1, 0);
  for (int b = 0; b < K; ++b) S[b + 1] = S[b] + fine.value[b] * fine.count[b], N[b + 1] = N[b] + fine.count[b];
  const long n = N[K];
  double best = 0;
  int bi = -1, bj = -1;
  for (int i = 0; i < K; ++i)
    for (int j = i; j < K; ++j) {
      if (i == 0 && j == K - 1) continue;
      const long n_in = N[j + 1] - N[i], n_out = n - n_in;
      if (n_in < min_side || n_out < min_side) continue;
      // A step is the same split as its complement: keep the smaller side as the run, so the
      // term's bias sits where the effect is and the model's cells carry the rest.
      if ((i == 0 || j == K - 1) && 2 * n_in > n) continue;
      const double s_in = S[j + 1] - S[i], d = s_in / n_in - (S[K] - s_in) / n_out;
      const double between = d * d * double(n_in) * double(n_out) / double(n);
      if (between > best) best = between, bi = i, bj = j;
    }
  BinnedTable w;
  if (bi < 0) {
    w.value = {0.0};
    w.count = {n};
    return w;
  }
  const long n_in = N[bj + 1] - N[bi];
  const double s_in = S[bj + 1] - S[bi];
  const double delta = (s_in / n_in - (S[K] - s_in) / (n - n_in)) * n_in / (n_in + 5.0);
  if (bi > 0) w.edges.push_back(fine.edges[bi - 1]), w.value.push_back(0), w.count.push_back(N[bi]);
  w.value.push_back(delta), w.count.push_back(n_in);
  if (bj < K - 1) w.edges.push_back(fine.edges[bj]), w.value.push_back(0), w.count.push_back(n - N[bj + 1]);
  return w;
}

Refit backfit_window(const std::vector<double>& x, const std::vector<double>& r, const std::vector<int>& cls,
                     const std::vector<int>& rb, int fine_bins, double cell_prior) {
  return backfit_with(x, r, cls, rb, cell_prior, [&](const std::vector<double>& y) {
    ClassTables t;
    t.pooled = fit_window(x, y, fine_bins);
    return t;
  });
}

BinnedTable fit_line_table(const std::vector<double>& x, const std::vector<double>& y) {
  BinnedTable t;
  const size_t n = x.size();
  if (n < 2) {
    t.value = {n ? y[0] : 0.0};
    t.count = {static_cast<long>(n)};
    return t;
  }
  std::vector<double> sorted = x;
  std::sort(sorted.begin(), sorted.end());
  const double q1 = sorted[n / 100], q99 = sorted[n - 1 - n / 100];
  double mx = 0, my = 0;
  for (size_t i = 0; i < n; ++i) mx += std::clamp(x[i], q1, q99), my += y[i];
  mx /= double(n), my /= double(n);
  double sxy = 0, sxx = 0;
  for (size_t i = 0; i < n; ++i) {
    const double dx = std::clamp(x[i], q1, q99) - mx;
    sxy += dx * (y[i] - my), sxx += dx * dx;
  }
  const double span = q99 - q1;
  if (!(span > 0) || !(sxx > 0)) {
    t.value = {my};
    t.count = {static_cast<long>(n)};
    return t;
  }
  const double b = sxy / sxx, a = my - b * mx;
  return line_table(a, b, q1, q99, x);
}

BinnedTable line_table(double a, double b, double q1, double q99, const std::vector<double>& x) {
  BinnedTable t;
  const double span = q99 - q1;
  const double lo = q1 - span, h = 3 * span / kLineBins;
  for (int k = 1; k < kLineBins; ++k) t.edges.push_back(lo + k * h);
  for (int k = 0; k < kLineBins; ++k) t.value.push_back(a + b * (lo + (k + 0.5) * h));
  t.count.assign(kLineBins, 0);
  for (double v : x) ++t.count[t.bin(v)];
  return t;
}

ClassTables fit_class_lines(const std::vector<double>& x, const std::vector<double>& y, const std::vector<int>& cls) {
  ClassTables t;
  t.pooled = fit_line_table(x, y);
  for (int c = 0; c < kObjectClassCount; ++c) {
    std::vector<double> xc, yc;
    for (size_t i = 0; i < x.size(); ++i)
      if (cls[i] == c) xc.push_back(x[i]), yc.push_back(y[i]);
    if (xc.size() >= 200) t.per_class[c] = fit_line_table(xc, yc), t.own[c] = true;
  }
  return t;
}

Refit backfit_line(const std::vector<double>& x, const std::vector<double>& r, const std::vector<int>& cls,
                   const std::vector<int>& rb, double cell_prior) {
  return backfit_with(x, r, cls, rb, cell_prior,
                      [&](const std::vector<double>& y) { return fit_class_lines(x, y, cls); });
}

namespace {

// Where each record's term value sits in a flat vector of the refit's table values: the pooled
// table's bins first, then each class's own table (if any).
struct Slots {
  int npooled = 0, total = 0;
  PerClass<int> offset{-1, -1, -1};
  std::vector<int> pooled, own;  // per record; own = -1 when the class uses the pooled table
  int used(size_t i) const { return own[i] >= 0 ? own[i] : pooled[i]; }
};

Slots slots_of(const ClassTables& t, const std::vector<double>& x, const std::vector<int>& cls) {
  Slots s;
  s.npooled = static_cast<int>(t.pooled.value.size());
  s.total = s.npooled;
  for (int c = 0; c < kObjectClassCount; ++c)
    if (t.own[c]) s.offset[c] = s.total, s.total += static_cast<int>(t.per_class[c].value.size());
  s.pooled.resize(x.size());
  s.own.assign(x.size(), -1);
  for (size_t i = 0; i < x.size(); ++i) {
    s.pooled[i] = t.pooled.bin(x[i]);
    if (cls[i] >= 0 && cls[i] < kObjectClassCount && t.own[cls[i]]) s.own[i] = s.offset[cls[i]] + t.per_class[cls[i]].bin(x[i]);
  }
  return s;
}

// The term's values refitted with its edges kept and record weights w: backfit's (or
// backfit_window's) four passes. `inside`: the window's bin (-1: a table).
std::vector<double> refit_values(const Slots& s, int inside, const std::vector<double>& r, const std::vector<int>& cell,
                                 int ncell, const std::vector<double>& w, double cell_prior) {
  std::vector<double> d(ncell, 0.0), v(s.total, 0.0), sum(s.total), cnt(s.total), dsum(ncell), dcnt(ncell);
  for (int pass = 0; pass < 4; ++pass) {
    std::fill(sum.begin(), sum.end(), 0.0), std::fill(cnt.begin(), cnt.end(), 0.0);
    for (size_t i = 0; i < r.size(); ++i) {
      if (w[i] == 0) continue;
      const double y = r[i] - d[cell[i]];
      sum[s.pooled[i]] += w[i] * y, cnt[s.pooled[i]] += w[i];
      if (s.own[i] >= 0) sum[s.own[i]] += w[i] * y, cnt[s.own[i]] += w[i];
    }
    if (inside >= 0) {
      double si = 0, ni = 0, so = 0, no = 0;
      for (int b = 0; b < s.npooled; ++b) (b == inside ? si : so) += sum[b], (b == inside ? ni : no) += cnt[b];
      std::fill(v.begin(), v.end(), 0.0);
      if (ni > 0 && no > 0) v[inside] = (si / ni - so / no) * ni / (ni + 5.0);
    } else {
      for (int b = 0; b < s.total; ++b) v[b] = cnt[b] > 0 ? sum[b] / (cnt[b] + 5.0) : 0.0;
    }
    std::fill(dsum.begin(), dsum.end(), 0.0), std::fill(dcnt.begin(), dcnt.end(), 0.0);
    for (size_t i = 0; i < r.size(); ++i)
      dsum[cell[i]] += w[i] * ((cell_prior > 0 ? 0.0 : r[i]) - v[s.used(i)]), dcnt[cell[i]] += w[i];
    for (int c = 0; c < ncell; ++c) d[c] = dcnt[c] >= 20 ? dsum[c] / (dcnt[c] + cell_prior) : 0.0;
  }
  return v;
}

// Empirical-Bayes factors of one table's bins [lo, hi) for their deviations from prior (only bins
// that hold fit data count): the kept value is prior + factor x (value - prior).
void pool_towards(const std::vector<double>& v, const std::vector<double>& prior, const std::vector<double>& se,
                  const std::vector<bool>& held, int lo, int hi, std::vector<double>& factor) {
  double acc = 0;
  int m = 0;
  for (int b = lo; b < hi; ++b)
    if (held[b]) acc += (v[b] - prior[b]) * (v[b] - prior[b]) - se[b] * se[b], ++m;
  const double tau2 = m > 0 ? std::max(0.0, acc / m) : 0.0;
  for (int b = lo; b < hi; ++b)
    factor[b] = !held[b] ? 1.0 : tau2 <= 0 ? 0.0 : tau2 / (tau2 + se[b] * se[b]);
}

// Records grouped by (class, range bin) cell and by track, each numbered in order of first sight.
struct Groups {
  std::vector<int> cell, track;  // per record
  int ncell = 0, ntracks = 0;
};

Groups groups_of(size_t n, const std::vector<int>& cls, const std::vector<int>& rb, const std::vector<int>& track) {
  Groups g;
  std::map<std::pair<int, int>, int> cell_id;
  g.cell.resize(n);
  for (size_t i = 0; i < n; ++i)
    g.cell[i] = cell_id.try_emplace({cls[i], rb[i]}, static_cast<int>(cell_id.size())).first->second;
  std::map<int, int> track_id;
  g.track.resize(n);
  for (size_t i = 0; i < n; ++i) g.track[i] = track_id.try_emplace(track[i], static_cast<int>(track_id.size())).first->second;
  g.ntracks = static_cast<int>(track_id.size()), g.ncell = static_cast<int>(cell_id.size());
  return g;
}

// The table's values laid out by slot, and which slots are judged (hold fit data; with a window,
// only the bin inside it).
void table_values(const Refit& f, const Slots& s, bool window, int inside, std::vector<double>& value,
                  std::vector<bool>& held) {
  value.assign(s.total, 0.0);
  held.assign(s.total, false);
  for (int b = 0; b < s.npooled; ++b) value[b] = f.table.pooled.value[b], held[b] = f.table.pooled.count[b] > 0;
  for (int c = 0; c < kObjectClassCount; ++c)
    if (s.offset[c] >= 0)
      for (size_t b = 0; b < f.table.per_class[c].value.size(); ++b)
        value[s.offset[c] + b] = f.table.per_class[c].value[b], held[s.offset[c] + b] = f.table.per_class[c].count[b] > 0;
  if (window)
    for (int b = 0; b < s.total; ++b) held[b] = b == inside;
}

// Bootstrap over tracks: each slot's standard deviation over the replicates' refits.
std::vector<double> bootstrap_se(const Slots& s, int inside, const std::vector<double>& r, const Groups& g,
                                 double cell_prior, int replicates, std::uint64_t seed) {
  const size_t n = r.size();
  std::mt19937_64 rng(seed);
  std::vector<double> s1(s.total, 0.0), s2(s.total, 0.0), wt(g.ntracks), w(n);
  for (int q = 0; q < replicates; ++q) {
    std::fill(wt.begin(), wt.end(), 0.0);
    for (int j = 0; j < g.ntracks; ++j) wt[rng() % static_cast<std::uint64_t>(g.ntracks)] += 1;
    for (size_t i = 0; i < n; ++i) w[i] = wt[g.track[i]];
    const auto v = refit_values(s, inside, r, g.cell, g.ncell, w, cell_prior);
    for (int b = 0; b < s.total; ++b) s1[b] += v[b], s2[b] += v[b] * v[b];
  }
  std::vector<double> se(s.total);
  for (int b = 0; b < s.total; ++b) {
    const double m = s1[b] / replicates;
    se[b] = std::sqrt(std::max(0.0, (s2[b] / replicates - m * m) * replicates / (replicates - 1.0)));
  }
  return se;
}

// Between-track and within-track variance of the residuals e (per track means, method of
// moments) over the records of class c (c < 0: every record, the pooled table).
std::array<double, 2> track_components(const std::vector<double>& e, const std::vector<int>& tr,
                                       const std::vector<int>& cls, int c) {
  std::map<int, std::array<double, 3>> tm;  // per track: sum, sum of squares, n
  for (size_t i = 0; i < e.size(); ++i)
    if (c < 0 || cls[i] == c) {
      auto& a = tm[tr[i]];
      a[0] += e[i], a[1] += e[i] * e[i], a[2] += 1;
    }
  double within = 0, nw = 0, m1 = 0, m2 = 0, inv = 0;
  for (const auto& [id, a] : tm) {
    const double m = a[0] / a[2];
    within += a[1] - a[2] * m * m, nw += a[2] - 1, m1 += m, m2 += m * m, inv += 1 / a[2];
  }
  const double T = static_cast<double>(tm.size());
  const double sw2 = nw > 0 ? within / nw : 0.0;
  const double sb2 = T > 1 ? std::max(0.0, (m2 - m1 * m1 / T) / (T - 1) - sw2 * inv / T) : 0.0;
  return {sb2, sw2};
}

// A floor under the bootstrap: a bin that holds one or two tracks shows the bootstrap no spread
// between tracks (resampling one track gives its own mean again), so the bin's variance is also
// taken as the table's between-track variance (of the residual after the term, per track means,
// method of moments) x sum(n_j^2) / n^2 over the bin's tracks + within-track variance / n.
void floor_se(const Refit& f, const Slots& s, bool window, int inside, const std::vector<double>& x,
              const std::vector<double>& r, const std::vector<int>& cls, const std::vector<int>& rb,
              const std::vector<int>& tr, std::vector<double>& se) {
  const size_t n = r.size();
  std::vector<double> e(n);
  for (size_t i = 0; i < n; ++i) e[i] = r[i] - f(cls[i], rb[i], x[i]);
  std::array<std::array<double, 2>, kObjectClassCount + 1> comp{};  // pooled, then per class
  comp[0] = track_components(e, tr, cls, -1);
  for (int c = 0; c < kObjectClassCount; ++c)
    if (s.offset[c] >= 0) comp[c + 1] = track_components(e, tr, cls, c);
  std::map<std::pair<int, int>, double> per_track;  // (slot, track) -> samples
  for (size_t i = 0; i < n; ++i) {
    per_track[{s.pooled[i], tr[i]}] += 1;
    if (s.own[i] >= 0) per_track[{s.own[i], tr[i]}] += 1;
  }
  std::vector<double> nb(s.total, 0.0), nb2(s.total, 0.0);
  for (const auto& [key, c] : per_track) nb[key.first] += c, nb2[key.first] += c * c;
  auto floor2 = [&](int b) {
    int scope = 0;
    for (int c = 0; c < kObjectClassCount; ++c)
      if (s.offset[c] >= 0 && b >= s.offset[c]) scope = c + 1;
    return nb[b] > 0 ? comp[scope][0] * nb2[b] / (nb[b] * nb[b]) + comp[scope][1] / nb[b] : 0.0;
  };
  if (window) {
    double out2 = 0, no = 0, no2 = 0;  // the outside of the window as one group
    for (int b = 0; b < s.npooled; ++b)
      if (b != inside) no += nb[b];
    std::map<int, double> ot;
    for (size_t i = 0; i < n; ++i)
      if (s.pooled[i] != inside) ot[tr[i]] += 1;
    for (const auto& [id, c] : ot) no2 += c * c;
    if (no > 0) out2 = comp[0][0] * no2 / (no * no) + comp[0][1] / no;
    se[inside] = std::sqrt(std::max(se[inside] * se[inside], floor2(inside) + out2));
  } else {
    for (int b = 0; b < s.total; ++b) se[b] = std::sqrt(std::max(se[b] * se[b], floor2(b)));
  }
}

// Each slot's shrinkage factor and prior: the pooled table towards zero, the class tables towards
// zero or (towards_pooled) towards the shrunk pooled table.
void shrink_factors(const Refit& f, const Slots& s, size_t n, const std::vector<double>& value,
                    const std::vector<double>& se, const std::vector<bool>& held, bool towards_pooled,
                    std::vector<double>& prior, std::vector<double>& factor) {
  prior.assign(s.total, 0.0);
  factor.assign(s.total, 1.0);
  pool_towards(value, prior, se, held, 0, s.npooled, factor);
  if (towards_pooled) {
    // A class bin's prior: the shrunk pooled table averaged over the class's records in that bin.
    std::vector<double> acc(s.total, 0.0), cnt(s.total, 0.0);
    for (size_t i = 0; i < n; ++i)
      if (s.own[i] >= 0) acc[s.own[i]] += value[s.pooled[i]] * factor[s.pooled[i]], cnt[s.own[i]] += 1;
    for (int b = s.npooled; b < s.total; ++b) prior[b] = cnt[b] > 0 ? acc[b] / cnt[b] : 0.0;
  }
  for (int c = 0; c < kObjectClassCount; ++c)
    if (s.offset[c] >= 0)
      pool_towards(value, prior, se, held, s.offset[c], s.offset[c] + static_cast<int>(f.table.per_class[c].value.size()),
                   factor);
}

// Write back: values x factor, and the factors and standard errors laid out like the table.
void write_shrunk(Refit& f, const Slots& s, const std::vector<double>& prior, const std::vector<double>& factor,
                  const std::vector<double>& se) {
  f.factor = f.table, f.se = f.table;
  auto put = [&](BinnedTable& t, BinnedTable& ft, BinnedTable& st, int off) {
    for (size_t b = 0; b < t.value.size(); ++b)
      t.value[b] = prior[off + b] + factor[off + b] * (t.value[b] - prior[off + b]), ft.value[b] = factor[off + b],
      st.value[b] = se[off + b];
  };
  put(f.table.pooled, f.factor.pooled, f.se.pooled, 0);
  for (int c = 0; c < kObjectClassCount; ++c)
    if (s.offset[c] >= 0) put(f.table.per_class[c], f.factor.per_class[c], f.se.per_class[c], s.offset[c]);
}

}  // namespace

void shrink_by_track_bootstrap(Refit& f, const std::vector<double>& x, const std::vector<double>& r,
                               const std::vector<int>& cls, const std::vector<int>& rb, const std::vector<int>& track,
                               bool window, bool towards_pooled, int replicates, std::uint64_t seed) {
  if (r.empty() || replicates < 2) return;
  const Slots s = slots_of(f.table, x, cls);
  int inside = -1;
  if (window) {
    for (int b = 0; b < s.npooled; ++b)
      if (f.table.pooled.value[b] != 0) inside = b;
    if (inside < 0) return;  // no window: nothing to shrink
  }
  const Groups g = groups_of(r.size(), cls, rb, track);
  std::vector<double> value, prior, factor;
  std::vector<bool> held;
  table_values(f, s, window, inside, value, held);
  std::vector<double> se = bootstrap_se(s, inside, r, g, f.cell_prior, replicates, seed);
  floor_se(f, s, window, inside, x, r, cls, rb, g.track, se);
  shrink_factors(f, s, r.size(), value, se, held, towards_pooled, prior, factor);
  write_shrunk(f, s, prior, factor, se);
  fit_cell_offsets(f, x, r, cls, rb);  // against the shrunk table
}

namespace {

// Target t's error on the fit records of class c with the term's part taken out, as samples for a
// noise refit (heading wrapped back to [-pi, pi)).
std::vector<sensor::ErrorSample> samples_without_term(const Refit& ref, int t, int c, const Split& fit,
                                                      const std::vector<double>& x, const std::vector<int>& cls,
                                                      const std::vector<int>& cells) {
  std::vector<sensor::ErrorSample> out;
  const auto s = relative_values(fit, ref);
  for (size_t i = 0; i < x.size(); ++i) {
    if (cls[i] != c) continue;
    const ObjectRecord& r = *fit.rec[i];
    double v = r.value[t] - ref.at(c, cells[i], x[i], s[i]);
    if (kTargetParam[t] == sensor::KpiParam::Heading) v = wrap(v);
    if (std::isfinite(v)) out.push_back({r.seq, r.track, r.frame, r.range_bin, r.visibility_bin, v});
  }
  return out;
}

// The variance of the per-track means of v (each record weighted alike), over the total count.
double between_track_variance(const std::vector<double>& v, const std::vector<std::pair<int, int>>& track) {
  std::map<std::pair<int, int>, std::pair<double, double>> acc;  // sum, n
  double total = 0;
  for (size_t i = 0; i < v.size(); ++i) acc[track[i]].first += v[i], acc[track[i]].second += 1, total += v[i];
  if (v.empty()) return 0;
  const double m = total / v.size();
  double s = 0;
  for (const auto& [id, a] : acc) s += a.second * std::pow(a.first / a.second - m, 2);
  return s / v.size();
}

}  // namespace

void shrink_noise_for_term(sensor::KpiModel& m, const Refit& ref, int t, const std::string& feature, const Split& fit,
                           const Winsor& w, int nvis, PerClass<bool> classes) {
  if (t == kDetectionTarget) return;
  const bool track_constant =
      feature == "size" || feature == "box_width" || feature == "box_height" || feature == "class";
  const sensor::KpiParam param = kTargetParam[t];
  const bool size_param =
      param == sensor::KpiParam::Length || param == sensor::KpiParam::Width || param == sensor::KpiParam::Height;
  sensor::FitOptions opt;
  opt.range_bin_edges = m.range_bin_edges, opt.visibility_bin_edges = m.visibility_bin_edges;
  const auto x = fit.column(feature_index(feature));
  const auto cls = fit.classes();
  const auto cells = fit.cells(t, nvis);
  const auto r = fit.clipped(w);
  const auto rel = relative_values(fit, ref);
  for (int c = 0; c < kObjectClassCount; ++c) {
    const auto it = m.classes.find(kObjectClasses[c]);
    if (it == m.classes.end() || !classes[c]) continue;
    std::vector<double> vals, res;
    std::vector<std::pair<int, int>> track;  // (sequence, track) of each value
    for (size_t i = 0; i < x.size(); ++i)
      if (cls[i] == c)
        vals.push_back(ref.at(c, cells[i], x[i], rel[i])), res.push_back(r[i]),
            track.emplace_back(fit.rec[i]->seq, fit.rec[i]->track);
    if (vals.size() < 20) continue;
    auto var = [](const std::vector<double>& v) {
      const double m = mean_of(v);
      double s = 0;
      for (double a : v) s += (a - m) * (a - m);
      return s / v.size();
    };
    const double V = var(res);
    double v = var(vals);
    if (V <= 0 || v <= 0) continue;
    sensor::ErrorModel& em = it->second.errors[int(param)];
    // The part of the term that is constant along a track comes out of the per-track constant: the
    // whole term for a feature constant along a track, else the variance of its per-track means
    // (an aspect or a speed changes slowly along a track, so the base's track_std carried most of
    // an effect on it; taken out of sigma alone, the re-simulated spread was term + the old
    // track_std and the class's histogram got worse, which dropped a correct term).
    const double between = track_constant ? v : between_track_variance(vals, track);
    if (between > 0) {
      const double take = std::min(between, em.track_std * em.track_std);
      em.track_std = std::sqrt(em.track_std * em.track_std - take);
      v -= take;
    }
    // The noise's shape (AR(1), innovation mixture) refitted on the error without the term, as
    // calibration fits it: where the term carried the error's correlation along a track or its
    // tails (a lag on the few fast objects), the base's were fitted to the term itself. The sigmas
    // keep the variance rule: the term's in-sample residual is narrower than the held-out one, so
    // sigmas refitted on it would understate the held-out spread (the width distribution's
    // intersection drops with box_width).
    const auto samples = samples_without_term(ref, t, c, fit, x, cls, cells);
    if (static_cast<int>(samples.size()) >= 2 * opt.min_samples) {
      const sensor::ErrorModel own = sensor::fit_error_model(samples, opt, size_param);
      em.ar1 = own.ar1, em.innovation = own.innovation;
    }
    const double f = std::sqrt(std::max(0.04, 1 - v / V));
    for (double& s : em.sigma) s *= f;
  }
}

double refit_probability(const Refit& ref, int cls, int cell, double x, double p) {
  const auto it = ref.d.find({cls, cell});
  double q = std::clamp(p + (it == ref.d.end() ? 0.0 : it->second), 0.0, 1.0);
  if (ref.has_gain()) q *= std::max(0.0, ref.gain(cls, x));
  return std::clamp(q + std::clamp(ref.table(cls, x), -1.0, 1.0), 0.0, 1.0);
}

Refit refit_on(const Fold& k, int t, int f, int nvis, int bins) {
  const Split& s = k.fit_r[t];
  return backfit(s.column(f), s.clipped(k.win[t]), s.classes(), s.cells(t, nvis), bins);
}

sensor::KpiModel with_term(const sensor::KpiModel& base, const Refit& ref, int t, const std::string& feature,
                           int nvis, PerClass<bool> classes) {
  sensor::KpiModel m = base;
  for (int c = 0; c < kObjectClassCount; ++c) {
    const auto it = m.classes.find(kObjectClasses[c]);
    if (it == m.classes.end() || !classes[c]) continue;
    sensor::ClassModel& cm = it->second;
    const BinnedTable& bt = ref.table.own[c] ? ref.table.per_class[c] : ref.table.pooled;
    // BinnedTable cut points -> the term's lower edges (bin 0 takes everything below edges[1]).
    sensor::ConditionalTerm ct;
    ct.feature = feature;
    if (ref.relative >= 0) ct.relative_to = kObjectFeatures[ref.relative];
    ct.edges.push_back(bt.edges.empty() ? 0.0 : bt.edges.front() - 1);
    ct.edges.insert(ct.edges.end(), bt.edges.begin(), bt.edges.end());
    ct.bias = bt.value;
    if (t == kDetectionTarget) {
      for (int rb = 0; rb < static_cast<int>(cm.detection_probability.size()); ++rb)
        for (int vb = 0; vb < static_cast<int>(cm.detection_probability[rb].size()); ++vb) {
          const auto d = ref.d.find({c, rb * nvis + vb});
          double& p = cm.detection_probability[rb][vb];
          if (d != ref.d.end()) p = std::clamp(p + d->second, 0.0, 1.0);
        }
      for (double& b : ct.bias) b = std::clamp(b, -1.0, 1.0);  // a probability shift
      if (ref.has_gain()) {  // a gain term's table of shifts is zero on the gain's own bins
        const BinnedTable& g = ref.gain.own[c] ? ref.gain.per_class[c] : ref.gain.pooled;
        ct.edges.assign(1, g.edges.empty() ? 0.0 : g.edges.front() - 1);
        ct.edges.insert(ct.edges.end(), g.edges.begin(), g.edges.end());
        ct.bias.assign(g.value.size(), 0.0);
        ct.scale = g.value;
        for (double& v : ct.scale) v = std::max(v, 0.0);
      }
      cm.detection_conditional = ct;
    } else {
      sensor::ErrorModel& em = cm.errors[int(kTargetParam[t])];
      for (int rb = 0; rb < static_cast<int>(em.mean.size()); ++rb) {
        const auto d = ref.d.find({c, rb});
        if (d != ref.d.end()) em.mean[rb] += d->second;
      }
      em.conditional = ct;
    }
  }
  m.source = base.source + "; plus the object loop's conditional term on " + feature + " (" +
             (t == kDetectionTarget ? std::string("detection probability") : kObjectTargets[t]) + ")";
  return m;
}

sensor::KpiModel with_term_and_noise(const sensor::KpiModel& base, const Refit& ref, int t, const std::string& feature,
                                     int nvis, const Split& fit, const Winsor& w, PerClass<bool> classes) {
  sensor::KpiModel m = with_term(base, ref, t, feature, nvis, classes);
  shrink_noise_for_term(m, ref, t, feature, fit, w, nvis, classes);
  return m;
}

}  // namespace lidarsim::qualify::obj
