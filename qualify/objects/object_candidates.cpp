#include "qualify/objects/object_candidates.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <numeric>
#include <sstream>

#include "common/error.h"
#include "qualify/objects/object_false_positives.h"
#include "qualify/objects/object_rate_gain.h"
#include "qualify/objects/object_spread_forms.h"
#include "qualify/report.h"
#include "sensor/kpi_fit.h"

namespace lidarsim::qualify::obj {

std::string to_string(Kind k) {
  switch (k) {
    case Kind::MeanTable: return "mean_table";
    case Kind::MeanWindow: return "mean_window";
    case Kind::MeanLine: return "mean_line";
    case Kind::RateTable: return "rate_table";
    case Kind::RateWindow: return "rate_window";
    case Kind::SpreadTable: return "spread_table";
    case Kind::SpreadWindow: return "spread_window";
    case Kind::SpreadGrowth: return "spread_growth";
    case Kind::SpreadLine: return "spread_line";
    case Kind::RateGain: return "rate_gain";
    case Kind::MeanRelativeLine: return "mean_relative_line";
  }
  return "?";
}
bool is_mean_line(Kind k) { return k == Kind::MeanLine || k == Kind::MeanRelativeLine; }
bool is_spread(Kind k) {
  return k == Kind::SpreadTable || k == Kind::SpreadWindow || k == Kind::SpreadGrowth || k == Kind::SpreadLine;
}
bool is_window(Kind k) {
  return k == Kind::MeanWindow || k == Kind::RateWindow || k == Kind::SpreadWindow || k == Kind::RateGain;
}
std::vector<Kind> kinds_for(int target) {
  if (target == kDetectionTarget) return {Kind::RateTable, Kind::RateWindow, Kind::RateGain};
  std::vector<Kind> kinds = {Kind::MeanTable,    Kind::MeanWindow,   Kind::MeanLine,  Kind::SpreadTable,
                             Kind::SpreadWindow, Kind::SpreadGrowth, Kind::SpreadLine};
  if (own_dimension(target) >= 0) kinds.push_back(Kind::MeanRelativeLine);
  return kinds;
}
bool kind_applies(Kind kind, const std::string& feature) { return kind != Kind::SpreadGrowth || feature == "range"; }

BinnedTable fit_scale_growth(const std::vector<double>& x, const std::vector<double>& u2, const std::vector<int>& cell,
                             double* k_out) {
  std::map<int, std::array<double, 4>> bins;  // per cell: sum x, n, min x, max x
  for (size_t i = 0; i < x.size(); ++i) {
    auto [it, fresh] = bins.try_emplace(cell[i], std::array<double, 4>{0, 0, x[i], x[i]});
    auto& b = it->second;
    b[0] += x[i], b[1] += 1, b[2] = std::min(b[2], x[i]), b[3] = std::max(b[3], x[i]);
  }
  std::vector<double> lr(x.size(), 0.0);  // log(x / its cell's mean x)
  for (size_t i = 0; i < x.size(); ++i) {
    const double m = bins[cell[i]][0] / bins[cell[i]][1];
    if (x[i] > 0 && m > 0) lr[i] = std::log(x[i] / m);
  }
  // Negative log-likelihood in k (u2 ~ scale^2 chi2_1): sum 2 k lr + u2 exp(-2 k lr); convex in k.
  auto nll = [&](double k) {
    double s = 0;
    for (size_t i = 0; i < x.size(); ++i) s += 2 * k * lr[i] + u2[i] * std::exp(-2 * k * lr[i]);
    return s;
  };
  double a = -1, b = 3;
  for (int it = 0; it < 60; ++it) {
    const double m1 = a + (b - a) / 3, m2 = b - (b - a) / 3;
    if (nll(m1) < nll(m2)) b = m2;
    else a = m1;
  }
  const double k = 0.5 * (a + b);
  if (k_out) *k_out = k;
  BinnedTable t;
  constexpr int kSub = 8;
  std::vector<std::array<double, 3>> spans;  // lo, hi, mean of each cell, by ascending range
  for (const auto& [c, v] : bins)
    if (v[1] > 0) spans.push_back({v[2], v[3], v[0] / v[1]});
  std::sort(spans.begin(), spans.end());
  for (size_t j = 0; j < spans.size(); ++j) {
    const auto [lo, hi, m] = spans[j];
    if (j > 0) t.edges.push_back(0.5 * (spans[j - 1][1] + lo));
    const double w = (hi - lo) / kSub;
    for (int q = 0; q < kSub; ++q) {
      if (q > 0) t.edges.push_back(lo + q * w);
      const double centre = lo + (q + 0.5) * w;
      t.value.push_back(centre > 0 && m > 0 ? std::pow(centre / m, k) : 1.0);
      t.count.push_back(0);
    }
  }
  if (t.value.empty()) t.value = {1.0}, t.count = {0};
  return t;
}

namespace {
// Per feature the base KPI model conditions on: which of its parts do (sensor/kpi_model.h).
struct ModelCondition {
  const char* feature;
  bool error_mean;      // ErrorModel::mean, on every error target (mean forms)
  bool error_spread;    // ErrorModel::sigma and visibility_std_scale (spread forms)
  bool detection_rate;  // ClassModel::detection_probability (rate forms)
};
// Only discrete features whose every level is a cell of the model: a form on them can only refit
// what the model has. Range is not one: the model holds it in fixed bins (sensor::FitOptions
// range_bin_edges, 10 m), and every candidate is fitted net of those cells (bias forms backfitted
// with the cell offsets, object_terms.h; spread forms in units of the cell's sd), so a range
// candidate scores only what lies between the model's edges (a detection edge at 47 m, a spread
// that grows within a bin) and is ranked like any other feature.
constexpr ModelCondition kObjectModelConditions[] = {
    {"class", true, true, true},       // one ClassModel per class
    {"occlusion", false, true, true},  // visibility_std_scale[visibility bin], detection_probability[.][visibility bin]
};
}  // namespace

bool used_by_model(const std::string& feature, int target, Kind kind) {
  for (const ModelCondition& m : kObjectModelConditions)
    if (feature == m.feature)
      return target == kDetectionTarget ? m.detection_rate : is_spread(kind) ? m.error_spread : m.error_mean;
  return false;
}
bool used_by_model(const Candidate& c) { return used_by_model(kObjectFeatures[c.feature], c.target, c.kind); }
bool clears_selection(const Candidate& c) { return !(c.selection_lower <= 0); }
bool line_over_table(const Candidate& c) { return !is_mean_line(c.kind) || !(c.vs_table[0] <= 0); }

namespace {
// Per block (line's after, table's after, before): the line's R^2 minus the table's.
double line_minus_table(const std::array<double, 3>& s) { return s[2] > 0 ? (s[1] - s[0]) / s[2] : 0; }
}  // namespace

void compare_lines_with_tables(std::vector<Candidate>& cands) {
  for (Candidate& line : cands) {
    if (!is_mean_line(line.kind)) continue;
    for (const Candidate& table : cands) {
      if (table.kind != Kind::MeanTable || table.feature != line.feature || table.target != line.target ||
          table.fold_set != line.fold_set || table.blocks.size() != line.blocks.size())
        continue;
      // Both are scored on the same held-out records against the same "before", so the blocks pair.
      BlockSums paired;
      for (size_t j = 0; j < line.blocks.size(); ++j)
        if (line.blocks[j][2] > 0) paired.push_back({line.blocks[j][0], table.blocks[j][0], line.blocks[j][1]});
      line.vs_table = block_bootstrap_interval(paired, line_minus_table);
    }
  }
}

double Effect::mean(int cls, int cell) const {
  const auto it = cell_mean.find({cls, cell});
  return it == cell_mean.end() ? 0.0 : it->second;
}
double Effect::sd(int cls, int cell) const {
  const auto it = cell_sd.find({cls, cell});
  return it != cell_sd.end() ? it->second : cls >= 0 && cls < kObjectClassCount ? class_sd[cls] : 1.0;
}

double Effect::level(int cls, int cell) const {
  if (cell_level.empty()) return 1.0;
  auto it = cell_level.find({cls, cell_sd.count({cls, cell}) ? cell : -1});
  return it != cell_level.end() ? it->second : 1.0;
}

double deviance(double y, double p) {
  p = std::clamp(p, 0.005, 0.995);
  return -2 * (y * std::log(p) + (1 - y) * std::log(1 - p));
}

namespace {

// The spread forms' variance window: the run of fine bins of x whose mean u^2 (squared residual in
// units of its cell's sd) differs most from the rest by the likelihood ratio of two variances.
BinnedTable fit_scale_window(const std::vector<double>& x, const std::vector<double>& u2, int fine_bins = 40,
                             long min_side = 30) {
  const BinnedTable fine = fit_binned_mean(x, u2, fine_bins, 0);
  const int K = static_cast<int>(fine.value.size());
  std::vector<double> S(K + 1, 0.0);
  std::vector<long> N(K + 1, 0);
  for (int b = 0; b < K; ++b) S[b + 1] = S[b] + fine.value[b] * fine.count[b], N[b + 1] = N[b] + fine.count[b];
  const long n = N[K];
  const double v_all = n ? std::max(S[K] / n, 1e-12) : 1;
  double best = 0;
  int bi = -1, bj = -1;
  for (int i = 0; i < K; ++i)
    for (int j = i; j < K; ++j) {
      if (i == 0 && j == K - 1) continue;
      const long n_in = N[j + 1] - N[i], n_out = n - n_in;
      if (n_in < min_side || n_out < min_side) continue;
      const double v_in = std::max((S[j + 1] - S[i]) / n_in, 1e-12), v_out = std::max((S[K] - S[j + 1] + S[i]) / n_out, 1e-12);
      const double lr = n_in * std::log(v_all / v_in) + n_out * std::log(v_all / v_out);
      if (lr > best) best = lr, bi = i, bj = j;
    }
  BinnedTable w;
  if (bi < 0) {
    w.value = {1.0};
    w.count = {n};
    return w;
  }
  const long n_in = N[bj + 1] - N[bi], n_out = n - n_in;
  // Shrunk towards the overall variance by 5 pseudo-samples each side.
  const double s_in = std::sqrt((S[bj + 1] - S[bi] + 5 * v_all) / (n_in + 5.0));
  const double s_out = std::sqrt((S[K] - S[bj + 1] + S[bi] + 5 * v_all) / (n_out + 5.0));
  if (bi > 0) w.edges.push_back(fine.edges[bi - 1]), w.value.push_back(s_out), w.count.push_back(N[bi]);
  w.value.push_back(s_in), w.count.push_back(n_in);
  if (bj < K - 1) w.edges.push_back(fine.edges[bj]), w.value.push_back(s_out), w.count.push_back(n - N[bj + 1]);
  return w;
}

double gaussian_deviance(double r, double sd) {
  sd = std::max(sd, 1e-9);
  return 2 * std::log(sd) + r * r / (sd * sd);
}

// Score statistics of per-track sums (after, before, n).
double spread_score(const std::array<double, 3>& s) { return s[2] > 0 ? 1 - std::exp(-(s[1] - s[0]) / s[2]) : 0; }

std::string form_of(const Effect& e) {
  const BinnedTable& t = is_spread(e.kind) ? e.scale : e.kind == Kind::RateGain ? e.bias.gain.pooled : e.bias.table.pooled;
  std::ostringstream o;
  if (is_mean_line(e.kind)) {
    // The pooled line's slope from two neighbouring bins of its table.
    const double slope = t.edges.size() >= 2 ? (t.value[2] - t.value[1]) / (t.edges[1] - t.edges[0]) : 0.0;
    if (e.kind == Kind::MeanRelativeLine)
      o << "relative line: " << kObjectFeatures[e.bias.relative] << " x (share " << fmt(t.value[t.bin(0)], 4)
        << " at 0, pooled slope " << fmt(slope, 4) << " per unit) (per class where >= 200 samples)";
    else
      o << "line, pooled slope " << fmt(slope, 4) << " per unit (per class where >= 200 samples)";
    return o.str();
  }
  if (e.kind == Kind::SpreadGrowth) {
    o << "growth within the model's range bins: sigma x (range / bin mean range)^" << fmt(e.growth, 3);
    return o.str();
  }
  if (e.kind == Kind::SpreadLine) {
    const double lo = t.edges.empty() ? 0.0 : t.edges.front() - (t.edges.size() > 1 ? t.edges[1] - t.edges[0] : 0.0);
    o << "line: sigma x (1 + b (x - " << fmt(lo, 3) << ")), " << fmt(t.value.back() / t.value.front(), 3)
      << " x from the 1 % to the 99 % quantile, level per class x range bin refitted";
    return o.str();
  }
  if (!is_window(e.kind)) {
    o << "table, " << t.value.size() << " bins" << (is_spread(e.kind) ? "" : " (per class where >= 200 samples)");
    return o.str();
  }
  if (t.edges.empty()) return "no window found";
  o << (t.edges.size() == 2 ? "window, edges" : "step, edge");
  for (double v : t.edges) o << " " << fmt(v, 3);
  o << "; " << (is_spread(e.kind) ? "scale" : e.kind == Kind::RateGain ? "gain on the probability" : "bias");
  for (double v : t.value) o << " " << fmt(v, 3);
  return o.str();
}

// The spread_line form (object_spread_forms.h) into e: its scale and the level of every group of
// cells e.sd() tells apart (a cell with its own sd, else its class).
void fit_spread_line(Effect& e, const std::vector<double>& x, const std::vector<double>& u2,
                     const std::vector<int>& cls, const std::vector<int>& cells) {
  std::map<std::pair<int, int>, int> id;
  std::vector<int> group(x.size());
  for (size_t i = 0; i < x.size(); ++i) {
    const std::pair<int, int> key{cls[i], e.cell_sd.count({cls[i], cells[i]}) ? cells[i] : -1};
    group[i] = id.try_emplace(key, static_cast<int>(id.size())).first->second;
  }
  const ScaleLine line = fit_scale_line(x, u2, group, static_cast<int>(id.size()));
  e.scale = line.scale;
  for (const auto& [key, k] : id) e.cell_level[key] = line.level[k];
}

}  // namespace

double score_of_sums(Kind kind, const std::array<double, 3>& sums) {
  return is_spread(kind) ? spread_score(sums) : r2_of_sums(sums);
}

Effect fit_effect(const Fold& k, int t, int f, Kind kind, int nvis, int bins) {
  Effect e;
  e.kind = kind;
  e.target = t;
  e.feature = f;
  const Split& s = k.fit_r[t];
  const auto x = s.column(f);
  const auto cls = s.classes();
  const auto cells = s.cells(t, nvis);
  // Binary outcomes have no heavy tails: rate forms fit the raw residual, with the cells shrunk as
  // the base model's are.
  const bool rate = t == kDetectionTarget;
  const auto r = rate ? s.r : s.clipped(k.win[t]);
  const double cell_prior = rate ? sensor::kDetectionPriorObjects : 0.0;
  switch (kind) {
    case Kind::MeanTable:
    case Kind::RateTable:
      e.bias = backfit(x, r, cls, cells, bins, cell_prior);
      if (k.shrink_terms != TermShrink::Off)
        shrink_by_track_bootstrap(e.bias, x, r, cls, cells, s.tracks(), false,
                                  k.shrink_terms == TermShrink::TowardsPooled);
      break;
    case Kind::MeanLine:
      // Not shrunk by the track bootstrap: two numbers per class, not a bin per few tracks.
      e.bias = backfit_line(x, r, cls, cells, cell_prior);
      break;
    case Kind::MeanRelativeLine:  // not shrunk, as mean_line
      e.bias = backfit_relative_line(x, r, s.column(own_dimension(t)), cls, cells, own_dimension(t));
      break;
    case Kind::MeanWindow:
    case Kind::RateWindow:
      e.bias = backfit_window(x, r, cls, cells, 4 * bins, cell_prior);
      if (k.shrink_terms != TermShrink::Off) shrink_by_track_bootstrap(e.bias, x, r, cls, cells, s.tracks(), true);
      break;
    case Kind::RateGain: {
      std::vector<double> y(s.rec.size());
      for (size_t i = 0; i < y.size(); ++i) y[i] = s.rec[i]->value[t];
      e.bias = fit_rate_gain(x, y, cls, cells, k.base, nvis, 4 * bins);
      break;
    }
    case Kind::SpreadTable:
    case Kind::SpreadWindow:
    case Kind::SpreadGrowth:
    case Kind::SpreadLine: {
      std::map<std::pair<int, int>, std::array<double, 3>> acc;  // sum, sum of squares, n
      PerClass<std::array<double, 3>> by_class{};
      for (size_t i = 0; i < r.size(); ++i) {
        auto& a = acc[{cls[i], cells[i]}];
        a[0] += r[i], a[1] += r[i] * r[i], a[2] += 1;
      }
      for (const auto& [key, a] : acc) {
        if (a[2] < 20) continue;
        const double m = a[0] / a[2];
        e.cell_mean[key] = m;
        e.cell_sd[key] = std::sqrt(std::max(a[1] / a[2] - m * m, 1e-18));
      }
      for (size_t i = 0; i < r.size(); ++i) {
        const double c = r[i] - e.mean(cls[i], cells[i]);
        auto& b = by_class[cls[i]];
        b[1] += c * c, b[2] += 1;
      }
      for (int c = 0; c < kObjectClassCount; ++c)
        e.class_sd[c] = by_class[c][2] > 0 ? std::sqrt(std::max(by_class[c][1] / by_class[c][2], 1e-18)) : 1;
      std::vector<double> u2(r.size());
      for (size_t i = 0; i < r.size(); ++i) {
        const double u = (r[i] - e.mean(cls[i], cells[i])) / e.sd(cls[i], cells[i]);
        u2[i] = u * u;
      }
      if (kind == Kind::SpreadLine) {
        fit_spread_line(e, x, u2, cls, cells);
      } else if (kind == Kind::SpreadGrowth) {
        e.scale = fit_scale_growth(x, u2, cells, &e.growth);
      } else if (kind == Kind::SpreadWindow) {
        e.scale = fit_scale_window(x, u2, 4 * bins);
      } else {
        for (double& v : u2) v -= 1;  // shrink towards a scale of 1
        e.scale = fit_binned_mean(x, u2, bins);
        for (double& v : e.scale.value) v = std::sqrt(std::max(v + 1, 0.01));
      }
      break;
    }
  }
  return e;
}

Losses held_losses(const Fold& k, const Effect& e, int nvis) {
  const int t = e.target;
  const Split& h = k.held_r[t];
  const auto x = h.column(e.feature);
  const auto cls = h.classes();
  const auto cells = h.cells(t, nvis);
  Losses L;
  L.before.resize(h.r.size());
  L.after.resize(h.r.size());
  if (t == kDetectionTarget) {
    for (size_t i = 0; i < h.r.size(); ++i) {
      const double y = h.rec[i]->value[t], p = y - h.r[i];
      L.before[i] = deviance(y, p);
      L.after[i] = deviance(y, refit_probability(e.bias, cls[i], cells[i], x[i], p));
    }
    return L;
  }
  const auto r = h.clipped(k.win[t]);
  if (!is_spread(e.kind)) {
    const double m = mean_of(k.fit_r[t].clipped(k.win[t]));
    const auto s = relative_values(h, e.bias);
    for (size_t i = 0; i < r.size(); ++i) {
      L.before[i] = std::pow(r[i] - m, 2);
      L.after[i] = std::pow(r[i] - e.bias.at(cls[i], cells[i], x[i], s[i]), 2);
    }
    return L;
  }
  L.x = x;
  for (size_t i = 0; i < r.size(); ++i) {
    const double c = r[i] - e.mean(cls[i], cells[i]), sd = e.sd(cls[i], cells[i]);
    const double sa = sd * e.level(cls[i], cells[i]) * e.scale(x[i]);
    L.before[i] = gaussian_deviance(c, sd);
    L.after[i] = gaussian_deviance(c, sa);
    L.centred.push_back(c);
    L.sd_before.push_back(sd);
    L.sd_after.push_back(sa);
  }
  return L;
}

double spread_error(const std::vector<double>& x, const std::vector<double>& centred, const std::vector<double>& sd,
                    int bins) {
  if (x.empty()) return 0;
  std::vector<size_t> order(x.size());
  std::iota(order.begin(), order.end(), size_t{0});
  std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return x[a] < x[b]; });
  double acc = 0;
  long total = 0;
  for (int b = 0; b < bins; ++b) {
    const size_t lo = order.size() * b / bins, hi = order.size() * (b + 1) / bins;
    if (hi <= lo) continue;
    double m2 = 0, s2 = 0;
    for (size_t i = lo; i < hi; ++i) m2 += centred[order[i]] * centred[order[i]], s2 += sd[order[i]] * sd[order[i]];
    if (m2 <= 0 || s2 <= 0) continue;
    const double l = 0.5 * std::log(m2 / s2);
    acc += l * l * double(hi - lo);
    total += static_cast<long>(hi - lo);
  }
  return total ? std::sqrt(acc / total) : 0;
}

Candidate judge_candidate(const std::array<Fold, 2>& folds, int t, int f, Kind kind, int nvis, int bins,
                          const std::array<std::vector<int>, 2>& block, size_t nblocks) {
  Candidate c;
  c.kind = kind;
  c.target = t;
  c.feature = f;
  BlockSums sums(nblocks, {0, 0, 0});
  std::array<double, 3> total{0, 0, 0};
  std::vector<double> raw_before, raw_after, sx, sc, sb, sa;
  double dev_b = 0, dev_a = 0;
  for (int k = 0; k < 2; ++k) {
    const Effect e = fit_effect(folds[k], t, f, kind, nvis, bins);
    if (k == 0) {
      c.form = form_of(e);
      if (is_spread(kind)) {
        const auto [lo, hi] = std::minmax_element(e.scale.value.begin(), e.scale.value.end());
        c.effect_size = *lo > 0 ? *hi / *lo : 0;
      } else {
        double m = 0;
        for (double v : e.bias.table.pooled.value) m = std::max(m, std::abs(v));
        for (int q = 0; q < kObjectClassCount; ++q)
          if (e.bias.table.own[q])
            for (double v : e.bias.table.per_class[q].value) m = std::max(m, std::abs(v));
        if (e.bias.has_gain())  // a gain's size: how far it moves the probability from 1 x
          for (double v : e.bias.gain.pooled.value) m = std::max(m, std::abs(v - 1));
        c.effect_size = m;
      }
    }
    const Losses L = held_losses(folds[k], e, nvis);
    for (size_t i = 0; i < L.before.size(); ++i) {
      auto& s = sums[block[k][i]];
      s[0] += L.after[i], s[1] += L.before[i], s[2] += 1;
      total[0] += L.after[i], total[1] += L.before[i], total[2] += 1;
    }
    dev_b += std::accumulate(L.before.begin(), L.before.end(), 0.0);
    dev_a += std::accumulate(L.after.begin(), L.after.end(), 0.0);
    if (is_spread(kind)) {
      sx.insert(sx.end(), L.x.begin(), L.x.end());
      sc.insert(sc.end(), L.centred.begin(), L.centred.end());
      sb.insert(sb.end(), L.sd_before.begin(), L.sd_before.end());
      sa.insert(sa.end(), L.sd_after.begin(), L.sd_after.end());
    } else if (t != kDetectionTarget) {
      // The raw (not winsorised) held-out residual before and after, as the loop reports it.
      const Split& h = folds[k].held_r[t];
      const auto x = h.column(f);
      const auto cls = h.classes(), cells = h.cells(t, nvis);
      const auto s = relative_values(h, e.bias);
      for (size_t i = 0; i < h.r.size(); ++i)
        raw_before.push_back(h.r[i]), raw_after.push_back(h.r[i] - e.bias.at(cls[i], cells[i], x[i], s[i]));
    }
  }
  BlockSums used;
  for (const auto& s : sums)
    if (s[2] > 0) used.push_back(s);
  c.n = static_cast<long>(total[2]);
  c.blocks = sums;
  if (is_spread(kind)) {
    c.score = spread_score(total);
    c.interval = block_bootstrap_interval(used, spread_score);
    c.error_before = spread_error(sx, sc, sb);
    c.error_after = spread_error(sx, sc, sa);
  } else {
    c.score = r2_of_sums(total);
    c.interval = block_bootstrap_interval(used, r2_of_sums);
    if (t == kDetectionTarget) c.error_before = dev_b / std::max(1.0, total[2]), c.error_after = dev_a / std::max(1.0, total[2]);
    else c.error_before = rms(raw_before), c.error_after = rms(raw_after);
  }
  return c;
}

sensor::KpiModel with_spread_term(const sensor::KpiModel& base, const Effect& e, const std::string& feature) {
  sensor::KpiModel m = base;
  const BinnedTable& bt = e.scale;
  sensor::ConditionalTerm ct;
  ct.feature = feature;
  ct.edges.push_back(bt.edges.empty() ? 0.0 : bt.edges.front() - 1);
  ct.edges.insert(ct.edges.end(), bt.edges.begin(), bt.edges.end());
  ct.bias.assign(bt.value.size(), 0.0);
  ct.scale = bt.value;
  for (double& s : ct.scale) s = std::max(s, 1e-3);
  for (int c = 0; c < kObjectClassCount; ++c) {
    const auto it = m.classes.find(kObjectClasses[c]);
    if (it == m.classes.end()) continue;
    sensor::ErrorModel& em = it->second.errors[int(kTargetParam[e.target])];
    em.conditional = ct;
    // spread_line: each range bin's sigma carries its refitted level (1 for the other forms).
    for (size_t rb = 0; rb < em.sigma.size(); ++rb) em.sigma[rb] *= e.level(c, static_cast<int>(rb));
  }
  m.source = base.source + "; plus the object loop's spread term on " + feature + " (" + kObjectTargets[e.target] +
             " sigma x scale per bin)";
  return m;
}

namespace {
// A mean_line term as the KPI model carries it (object_terms.h fit_line_table): kLineBins bins of
// equal width; a table or window has at most --bins bins of equal count.
bool is_line_term(const sensor::ConditionalTerm& ct) {
  if (ct.edges.size() != static_cast<size_t>(kLineBins)) return false;
  const double h = ct.edges[2] - ct.edges[1];
  for (size_t k = 2; k < ct.edges.size(); ++k)
    if (!(std::abs(ct.edges[k] - ct.edges[k - 1] - h) <= 1e-6 * std::max(1.0, std::abs(h)))) return false;
  return h > 0;
}
}  // namespace

sensor::KpiModel refit_recipe(const TrackingData& data, const std::vector<int>& fit_idx, const sensor::KpiModel& recipe,
                              int bins, TermShrink shrink_terms, bool pool_track_spread, std::uint64_t seed) {
  Fold fold;
  fold.pool_track_spread = pool_track_spread;
  make_fold(fold, data, fit_idx, {}, sensor::FitOptions{});
  fold.shrink_terms = shrink_terms;
  const int nvis = fold.base.visibility_bins();
  sensor::KpiModel m = fold.base;
  for (int t = 0; t < kObjectTargetCount; ++t) {
    // The term on t and the classes that carry it (a term may be kept for some classes only).
    const sensor::ConditionalTerm* ct = nullptr;
    PerClass<bool> classes{};
    for (int c = 0; c < kObjectClassCount; ++c) {
      const auto cm = recipe.classes.find(kObjectClasses[c]);
      if (cm == recipe.classes.end()) continue;
      const sensor::ConditionalTerm& ctc =
          t == kDetectionTarget ? cm->second.detection_conditional : cm->second.errors[int(kTargetParam[t])].conditional;
      if (!ctc.present()) continue;
      classes[c] = true;
      if (!ct) ct = &ctc;
    }
    if (!ct) continue;
    const auto it = std::find(kObjectFeatures.begin(), kObjectFeatures.end(), ct->feature);
    if (it == kObjectFeatures.end()) continue;
    const int f = static_cast<int>(it - kObjectFeatures.begin());
    if (!ct->relative_to.empty() && (own_dimension(t) < 0 || ct->relative_to != kObjectFeatures[own_dimension(t)]))
      throw Error("refit of the model's terms: errors." + kObjectTargets[t] + ".conditional.relative_to is \"" +
                  ct->relative_to + "\"; the object loop refits a relative term only as a share of the target's own size");
    const Kind kind = t == kDetectionTarget ? (ct->scale.empty() ? Kind::RateTable : Kind::RateGain)
                      : !ct->scale.empty()   ? (is_line_term(*ct) ? Kind::SpreadLine : Kind::SpreadTable)
                      : !ct->relative_to.empty() ? Kind::MeanRelativeLine
                      : is_line_term(*ct)    ? Kind::MeanLine
                                             : Kind::MeanTable;
    const Effect e = fit_effect(fold, t, f, kind, nvis, bins);
    if (is_spread(kind)) m = with_spread_term(m, e, ct->feature);
    else if (t == kDetectionTarget) m = with_term(m, e.bias, t, ct->feature, nvis, classes);
    else m = with_term_and_noise(m, e.bias, t, ct->feature, nvis, fold.fit_r[t], fold.win[t], classes);
  }
  // The false-positive table, refitted with the loop's form: a window or step has at most 3 bins; a
  // table in one class only (of several) is that class's own candidate.
  int tables = 0;
  for (const auto& [name, cm] : recipe.classes) tables += cm.fp_table.present();
  for (const auto& [name, cm] : recipe.classes) {
    const sensor::FalsePositiveTable& ft = cm.fp_table;
    const auto it = std::find(kFpFeatures.begin(), kFpFeatures.end(), ft.feature);
    if (!ft.present() || it == kFpFeatures.end()) continue;
    FpCandidate c;
    c.feature = static_cast<int>(it - kFpFeatures.begin());
    c.window = ft.edges.size() <= 3;
    const auto cls = std::find(kObjectClasses.begin(), kObjectClasses.end(), name);
    if (tables == 1 && recipe.classes.size() > 1 && cls != kObjectClasses.end())
      c.cls = static_cast<int>(cls - kObjectClasses.begin());
    m = with_fitted_fp_table(m, fold, c, bins);
    break;
  }
  // And the false positives' persistence (ghost tracks), where the recipe has it.
  for (const auto& [name, cm] : recipe.classes)
    if (cm.fp_persistence.present()) return with_fp_persistence(m, data, fold.fit_idx, fold.fit_set, seed);
  return m;
}

}  // namespace lidarsim::qualify::obj
