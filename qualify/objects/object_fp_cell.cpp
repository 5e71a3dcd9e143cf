// The fp_rate_cell form of the object loop's false positives (object_fp_cell.h).
#include "qualify/objects/object_fp_cell.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "qualify/windows.h"

namespace lidarsim::qualify::obj {

namespace {

constexpr int kUniformPoints = 64;   // a uniform stretch as weighted points (its quantiles are exact)
constexpr double kPriorCount = 1;    // pseudo false positives a background share is shrunk with
// A hot spot, not a modulation: the rectangle spans at most kCellSide of the range and of the
// azimuth the fitted false positives span (so the background's shares, estimated beside it, rest on
// at least as much of the field) and holds at most kCellBackgroundShare of the background's false
// positives, and inside it the cell's are at least kCellContrast times the background's there.
// The base's two marginals hold a broad joint tilt well enough, and a rectangle over most of the field
// (a uniform placement that fits the held-out counts better than 21 noisy quantiles: a control set's
// uniform clutter) would otherwise pass as a cell on data without one.
constexpr double kCellContrast = 3;
constexpr double kCellBackgroundShare = 0.25;
constexpr double kCellSide = 0.5;

// One class's fit false positives on the fine grid: counts per (range bin, azimuth bin), with the
// row and column sums as prefix sums so a rectangle's outside sums cost O(K).
struct ClassGrid {
  int kr = 0, ka = 0;
  std::vector<double> n;              // kr x ka
  std::vector<double> row_pre, col_pre;  // row i: prefix over azimuth bins (ka + 1); column j: over range bins
  std::vector<double> row_all, col_all;
  double total = 0;
  double at(int i, int j) const { return n[i * ka + j]; }
};

ClassGrid class_grid(const std::vector<std::array<int, 2>>& bins, int kr, int ka) {
  ClassGrid G;
  G.kr = kr, G.ka = ka;
  G.n.assign(kr * ka, 0.0);
  for (const auto& [i, j] : bins) G.n[i * ka + j] += 1;
  G.row_pre.assign(kr * (ka + 1), 0.0), G.col_pre.assign(ka * (kr + 1), 0.0);
  G.row_all.assign(kr, 0.0), G.col_all.assign(ka, 0.0);
  for (int i = 0; i < kr; ++i)
    for (int j = 0; j < ka; ++j) {
      G.row_pre[i * (ka + 1) + j + 1] = G.row_pre[i * (ka + 1) + j] + G.at(i, j);
      G.col_pre[j * (kr + 1) + i + 1] = G.col_pre[j * (kr + 1) + i] + G.at(i, j);
      G.row_all[i] += G.at(i, j), G.col_all[j] += G.at(i, j);
    }
  G.total = static_cast<double>(bins.size());
  return G;
}

struct Rect {
  int i0 = 0, i1 = -1, j0 = 0, j1 = -1;  // fine bins, inclusive
};

// The Poisson log-likelihood of one class's fine-grid counts under background x cell for the
// rectangle (object_fp_cell.h); adds the cell's count, the background's inside the rectangle and the
// background's in all to `cell_bg`.
double rect_loglik(const ClassGrid& G, const Rect& R, const std::vector<double>& wr, const std::vector<double>& wa,
                   std::array<double, 3>& cell_bg) {
  if (G.total <= 0) return 0;
  const int kr = G.kr, ka = G.ka;
  std::vector<double> p(kr), q(ka);
  double sp = 0, sq = 0, in = 0;
  for (int i = 0; i < kr; ++i) {
    const double inside = G.row_pre[i * (ka + 1) + R.j1 + 1] - G.row_pre[i * (ka + 1) + R.j0];
    p[i] = G.row_all[i] - inside + kPriorCount * G.row_all[i] / G.total, sp += p[i];
    if (i >= R.i0 && i <= R.i1) in += inside;
  }
  for (int j = 0; j < ka; ++j) {
    const double inside = G.col_pre[j * (kr + 1) + R.i1 + 1] - G.col_pre[j * (kr + 1) + R.i0];
    q[j] = G.col_all[j] - inside + kPriorCount * G.col_all[j] / G.total, sq += q[j];
  }
  double PI = 0, QJ = 0, wi = 0, wj = 0;
  for (int i = R.i0; i <= R.i1; ++i) PI += p[i] / sp, wi += wr[i];
  for (int j = R.j0; j <= R.j1; ++j) QJ += q[j] / sq, wj += wa[j];
  const double out = G.total - in;
  const double bt = PI * QJ < 1 ? out / (1 - PI * QJ) : 0;
  const double cell = std::max(0.0, in - bt * PI * QJ);
  cell_bg[0] += cell, cell_bg[1] += bt * PI * QJ, cell_bg[2] += bt;
  double ll = -(bt + cell);
  for (int i = 0; i < kr; ++i)
    for (int j = 0; j < ka; ++j) {
      const double y = G.at(i, j);
      if (y <= 0) continue;
      double mu = bt * p[i] / sp * q[j] / sq;
      if (i >= R.i0 && i <= R.i1 && j >= R.j0 && j <= R.j1) mu += cell * wr[i] / wi * wa[j] / wj;
      ll += y * std::log(std::max(mu, 1e-12));
    }
  return ll;
}

// Fine-bin widths in the feature's value (the outer bins end at the fitted values' extremes).
std::vector<double> bin_widths(const std::vector<double>& edges, double lo, double hi) {
  std::vector<double> w(edges.size() + 1);
  for (size_t k = 0; k < w.size(); ++k) {
    const double a = k == 0 ? lo : edges[k - 1], b = k == edges.size() ? hi : edges[k];
    w[k] = std::max(b - a, 1e-9);
  }
  return w;
}

// The width of fine bins a..b.
double span(const std::vector<double>& w, int a, int b) {
  double s = 0;
  for (int k = a; k <= b; ++k) s += w[k];
  return s;
}

// Values spread evenly over [lo, hi) with `weight` in all.
void add_uniform(std::vector<std::pair<double, double>>& v, double lo, double hi, double weight) {
  for (int k = 0; k < kUniformPoints; ++k) v.push_back({lo + (hi - lo) * (k + 0.5) / kUniformPoints, weight / kUniformPoints});
  v.push_back({lo, 0.0}), v.push_back({hi, 0.0});  // the stretch's ends, so the quantiles reach them
}

bool in_span(double x, double lo, double hi) { return x >= lo && x < hi; }

// Class c's components of the cell model (below, inside, above the cell's ranges; only the bins the
// cuts make), from its fit false positives; false when it has no cell (nothing beyond the background).
// `box` decides membership (open ends infinite), `place` is where the cell's false positives are spread.
bool cell_components(FpModel& m, const FpData& fit, int c, const std::array<double, 4>& box,
                     const std::array<double, 4>& place, const std::array<double, 4>& open, const FpComponent& base,
                     double& cell_rate) {
  std::vector<double> rb, ab;  // background samples: range (outside the azimuths), azimuth (outside the ranges)
  double in = 0, n = 0;
  for (const auto& r : fit.fps) {
    if (r.cls != c) continue;
    const bool rin = in_span(r.range, box[0], box[1]), ain = in_span(r.azimuth, box[2], box[3]);
    if (!ain) rb.push_back(r.range);
    if (!rin) ab.push_back(r.azimuth);
    in += rin && ain, n += 1;
  }
  if (rb.size() < 2 || ab.size() < 2 || base.sq.empty()) return false;
  auto share = [](const std::vector<double>& v, double lo, double hi) {
    return std::count_if(v.begin(), v.end(), [&](double x) { return in_span(x, lo, hi); }) / double(v.size());
  };
  const double P = share(rb, box[0], box[1]), Q = share(ab, box[2], box[3]);
  const double bt = P * Q < 1 ? (n - in) / (1 - P * Q) : 0;
  const double cell = in - bt * P * Q;
  if (cell <= 0) return false;
  const double frames = std::max<size_t>(1, fit.frames.size());
  cell_rate = cell / frames;
  const double inf = std::numeric_limits<double>::infinity();
  const std::array<std::array<double, 2>, 3> spans = {{{-inf, box[0]}, {box[0], box[1]}, {box[1], inf}}};
  m.comps[c].clear();
  for (int b = 0; b < 3; ++b) {
    if ((b == 0 && open[0] > 0) || (b == 2 && open[1] > 0)) continue;  // the cell reaches that end
    const auto [lo, hi] = spans[b];
    const double bg = bt * share(rb, lo, hi);
    std::vector<std::pair<double, double>> rv, av;
    long nb = std::count_if(rb.begin(), rb.end(), [&](double x) { return in_span(x, lo, hi); });
    for (double x : rb)
      if (in_span(x, lo, hi)) rv.push_back({x, bg / nb});
    for (double x : ab) av.push_back({x, bg / ab.size()});
    if (b == 1) add_uniform(rv, place[0], place[1], cell), add_uniform(av, place[2], place[3], cell);
    FpComponent k;
    k.rate = (bg + (b == 1 ? cell : 0)) / frames;
    k.rq = weighted_quantiles(rv), k.aq = weighted_quantiles(av), k.sq = base.sq;
    // The bin's range placement reaches its edges (the KPI manager draws between quantiles).
    if (!k.rq.empty() && std::isfinite(lo)) k.rq.front() = std::min(k.rq.front(), lo);
    if (!k.rq.empty() && std::isfinite(hi)) k.rq.back() = std::max(k.rq.back(), hi);
    if (k.rq.empty() || k.aq.empty()) k.rate = 0;
    m.comps[c].push_back(k);
  }
  return true;
}

}  // namespace

std::vector<double> weighted_quantiles(std::vector<std::pair<double, double>> v) {
  std::sort(v.begin(), v.end());
  double total = 0;
  for (const auto& e : v) total += e.second;
  if (v.size() < 2 || !(total > 0)) return {};
  // The piecewise-linear CDF through (value, weight before it + half its own), pinned at the ends.
  std::vector<double> t(v.size());
  double before = 0;
  for (size_t k = 0; k < v.size(); ++k) t[k] = (before + v[k].second / 2) / total, before += v[k].second;
  t.front() = 0, t.back() = 1;
  std::vector<double> q(kFpQuantiles);
  size_t k = 0;
  for (int i = 0; i < kFpQuantiles; ++i) {
    const double p = double(i) / (kFpQuantiles - 1);
    while (k + 2 < v.size() && t[k + 1] < p) ++k;
    const double f = t[k + 1] > t[k] ? std::clamp((p - t[k]) / (t[k + 1] - t[k]), 0.0, 1.0) : 0.0;
    q[i] = v[k].first + f * (v[k + 1].first - v[k].first);
  }
  return q;
}

FpModel fit_fp_cell(const FpData& fit, const sensor::KpiModel& base, int bins, const FpGrid& g,
                    const PerClass<double>& floor, int cls) {
  FpModel m = fp_base(base, fit);
  m.feature = 0, m.cls = cls;
  std::vector<double> xr, xa;
  for (const auto& r : fit.fps)
    if (cls < 0 || r.cls == cls) xr.push_back(r.range), xa.push_back(r.azimuth);
  if (xr.size() < 2 * static_cast<size_t>(kFpWindowSide)) return m.compile(g, floor), m;
  const std::vector<double> er = equal_count_edges(xr, 2 * bins), ea = equal_count_edges(xa, 2 * bins);
  const int kr = static_cast<int>(er.size() + 1), ka = static_cast<int>(ea.size() + 1);
  const auto [rlo, rhi] = std::minmax_element(xr.begin(), xr.end());
  const auto [alo, ahi] = std::minmax_element(xa.begin(), xa.end());
  const std::vector<double> wr = bin_widths(er, *rlo, *rhi), wa = bin_widths(ea, *alo, *ahi);
  PerClass<std::vector<std::array<int, 2>>> cells;
  for (const auto& r : fit.fps)
    if (cls < 0 || r.cls == cls) cells[r.cls].push_back({fp_cut_bin(er, r.range), fp_cut_bin(ea, r.azimuth)});
  std::vector<ClassGrid> grids;
  for (int c = 0; c < kObjectClassCount; ++c)
    if (!cells[c].empty()) grids.push_back(class_grid(cells[c], kr, ka));
  ClassGrid all = class_grid([&] {
    std::vector<std::array<int, 2>> v;
    for (const auto& c : cells) v.insert(v.end(), c.begin(), c.end());
    return v;
  }(), kr, ka);
  // Every rectangle of fine bins that holds kFpWindowSide and leaves some range and azimuth outside.
  Rect best;
  double best_ll = -std::numeric_limits<double>::infinity();
  for (int i0 = 0; i0 < kr; ++i0)
    for (int i1 = i0; i1 < kr; ++i1) {
      if (i0 == 0 && i1 == kr - 1) continue;
      for (int j0 = 0; j0 < ka; ++j0)
        for (int j1 = j0; j1 < ka; ++j1) {
          if (j0 == 0 && j1 == ka - 1) continue;
          double in = 0;
          for (int i = i0; i <= i1; ++i) in += all.row_pre[i * (ka + 1) + j1 + 1] - all.row_pre[i * (ka + 1) + j0];
          if (in < kFpWindowSide) continue;
          if (span(wr, i0, i1) > kCellSide * span(wr, 0, kr - 1) || span(wa, j0, j1) > kCellSide * span(wa, 0, ka - 1))
            continue;
          const Rect R{i0, i1, j0, j1};
          double ll = 0;
          std::array<double, 3> cell_bg{0, 0, 0};
          for (const ClassGrid& G : grids) ll += rect_loglik(G, R, wr, wa, cell_bg);
          if (cell_bg[0] < kCellContrast * cell_bg[1] || cell_bg[1] > kCellBackgroundShare * cell_bg[2]) continue;
          if (ll > best_ll) best_ll = ll, best = R;
        }
    }
  if (best.i1 < 0) return m.compile(g, floor), m;
  const double inf = std::numeric_limits<double>::infinity();
  // Open ends (the rectangle reaches the fitted values' extremes) extend to infinity for membership
  // and to the extremes for the uniform placement.
  std::array<double, 4> box = {best.i0 > 0 ? er[best.i0 - 1] : *rlo, best.i1 < kr - 1 ? er[best.i1] : *rhi,
                               best.j0 > 0 ? ea[best.j0 - 1] : *alo, best.j1 < ka - 1 ? ea[best.j1] : *ahi};
  const std::array<double, 4> open = {best.i0 == 0 ? 1.0 : 0.0, best.i1 == kr - 1 ? 1.0 : 0.0, 0, 0};
  FpModel out = m;
  out.cuts.clear();
  if (best.i0 > 0) out.cuts.push_back(box[0]);
  if (best.i1 < kr - 1) out.cuts.push_back(box[1]);
  std::array<double, 4> member = box;
  if (open[0] > 0) member[0] = -inf;
  if (open[1] > 0) member[1] = inf;
  if (best.j0 == 0) member[2] = -inf;
  if (best.j1 == ka - 1) member[3] = inf;
  out.cell_rate = 0;
  bool any = false;
  for (int c = 0; c < kObjectClassCount; ++c) {
    if (cls >= 0 && c != cls) continue;
    double rate = 0;
    if (cell_components(out, fit, c, member, box, open, m.comps[c][0], rate)) out.cell_rate += rate, any = true;
    else out.comps[c] = m.comps[c];  // no cell in this class: the base's
  }
  if (!any) return m.compile(g, floor), m;
  out.cell = box;
  out.compile(g, floor);
  return out;
}

}  // namespace lidarsim::qualify::obj
