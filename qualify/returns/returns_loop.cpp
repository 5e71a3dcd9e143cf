// The closed loop on the return rate: cells, candidate multipliers, scan folds, held-out Bernoulli
// deviance and the max-T bound (qualify/returns/returns_loop.h says what and why).
#include "qualify/returns/returns_loop.h"

#include <algorithm>
#include <cmath>
#include <map>

#include "common/error.h"
#include "pgm/materials.h"
#include "qualify/returns/max_t.h"
#include "qualify/similarity.h"
#include "sensor/return_model.h"

namespace lidarsim::qualify {

using nlohmann::json;

std::vector<ReturnCell> return_cells(const pgm::ReturnTarget& t, const pgm::BeamLayout& layout, int scan) {
  if (t.rows != layout.rows() || t.cols != layout.columns)
    throw Error("return loop: a target of " + std::to_string(t.rows) + " x " + std::to_string(t.cols) +
                " cells does not match the layout " + layout.name);
  std::vector<ReturnCell> out;
  out.reserve(static_cast<std::size_t>(t.returns + t.drops));
  for (int r = 0; r < t.rows; ++r)
    for (int c = 0; c < t.cols; ++c) {
      const std::size_t i = static_cast<std::size_t>(r) * t.cols + c;
      if (t.label[i] == pgm::ReturnLabel::Sky) continue;
      ReturnCell cell;
      cell.scan = scan, cell.row = r, cell.col = c;
      cell.range = t.range[i];
      cell.class_id = std::clamp(t.class_id[i], 0, pgm::class_count() - 1);
      cell.material = pgm::default_material(cell.class_id);
      cell.height = static_cast<float>(t.range[i] * std::sin(layout.elevations_rad[r]));
      cell.azimuth_deg = static_cast<float>(360.0 * (c + 0.5) / t.cols);
      cell.returned = t.label[i] == pgm::ReturnLabel::Return;
      out.push_back(cell);
    }
  return out;
}

namespace {

constexpr int kRangeBins = 24;          // 5 m, as the base table's
constexpr double kEps = 1e-4;

// How a candidate keys a cell (the keys the simulation's multiplier terms use).
using Key = sensor::ReturnKey;
constexpr int kKeys = 8;

struct Spec {
  std::string feature;
  TermForm form;
  Key key;
};

const std::vector<Spec>& specs() {
  static const std::vector<Spec> s = {
      {"laser", TermForm::table, Key::Laser},       {"laser", TermForm::window, Key::Laser},
      {"range", TermForm::table, Key::Range5m},       {"range", TermForm::window, Key::Range5m},
      {"class", TermForm::table, Key::Class},       {"material", TermForm::table, Key::Material},
      {"azimuth", TermForm::table, Key::Azimuth10}, {"azimuth", TermForm::window, Key::Azimuth5},
      {"height", TermForm::table, Key::Height},     {"height", TermForm::window, Key::Height},
      {"class x range", TermForm::step, Key::ClassRange5m}};
  return s;
}

int key_size(Key k, int rows) { return sensor::return_key_size(k, rows); }
int key_of(Key k, const ReturnCell& c) { return sensor::return_key(k, c.row, c.range, c.class_id, c.azimuth_deg, c.height); }

// Cells, returns and predicted returns per key.
struct Sums {
  std::vector<double> n, y, p;
  explicit Sums(int size = 0) : n(size), y(size), p(size) {}
};

double bernoulli_deviance(bool y, double p) {
  p = std::clamp(p, kEps, 1 - kEps);
  return -2 * (y ? std::log(p) : std::log(1 - p));
}

// Binomial log-likelihood gain of the rate y/n over the predicted q = p/n on aggregated counts.
double llr(double n, double y, double p) {
  if (n <= 0) return 0;
  const double r = std::clamp(y / n, kEps, 1 - kEps), q = std::clamp(p / n, kEps, 1 - kEps);
  return y * std::log(r / q) + (n - y) * std::log((1 - r) / (1 - q));
}

double shrunk(double y, double p, double s) { return (y + s) / (p + s); }

// The multipliers of one candidate from the fit cells' sums of its key (1 = no change).
std::vector<double> fit_multipliers(const Spec& spec, const Sums& s, double shrink, json* fitted) {
  const int K = static_cast<int>(s.n.size());
  std::vector<double> m(K, 1.0);
  if (spec.form == TermForm::table) {
    for (int k = 0; k < K; ++k) m[k] = s.n[k] > 0 ? shrunk(s.y[k], s.p[k], shrink) : 1.0;
    if (fitted) {
      (*fitted)["bins"] = K;
      (*fitted)["multiplier"] = m;
      (*fitted)["cells"] = s.n;
    }
    return m;
  }
  const double kMinCells = 200;
  if (spec.form == TermForm::window) {
    const bool circular = spec.key == Key::Azimuth5;
    double best = 0, bm = 1;
    int ba = -1, bb = -1;
    for (int a = 0; a < K; ++a) {
      double n = 0, y = 0, p = 0;
      for (int len = 1; len < K; ++len) {  // never the whole circle / axis: that is the table's global level
        const int b = a + len - 1;
        if (!circular && b >= K) break;
        const int k = b % K;
        n += s.n[k], y += s.y[k], p += s.p[k];
        if (n < kMinCells) continue;
        const double g = llr(n, y, p);
        if (g > best) best = g, ba = a, bb = b, bm = shrunk(y, p, shrink);
      }
    }
    if (ba >= 0)
      for (int b = ba; b <= bb; ++b) m[b % K] = bm;
    if (fitted) *fitted = {{"bins", K}, {"first_bin", ba}, {"last_bin", bb % std::max(K, 1)}, {"multiplier", bm}};
    return m;
  }
  // step: one class beyond a range bin
  const int C = K / kRangeBins;
  double best = 0, bm = 1;
  int bc = -1, ba = -1;
  for (int c = 0; c < C; ++c) {
    double n = 0, y = 0, p = 0;
    for (int a = kRangeBins - 1; a >= 1; --a) {  // from the far end down to the second bin (beyond 5 m)
      const int k = c * kRangeBins + a;
      n += s.n[k], y += s.y[k], p += s.p[k];
      if (n < kMinCells) continue;
      const double g = llr(n, y, p);
      if (g > best) best = g, bc = c, ba = a, bm = shrunk(y, p, shrink);
    }
  }
  if (bc >= 0)
    for (int a = ba; a < kRangeBins; ++a) m[bc * kRangeBins + a] = bm;
  if (fitted)
    *fitted = {{"class", bc >= 0 ? pgm::class_name(bc) : std::string("-")}, {"beyond_m", ba * 5.0}, {"multiplier", bm}};
  return m;
}

sensor::ReturnModel fit_base(const std::vector<ReturnCell>& ref, const pgm::BeamLayout& layout,
                             const std::vector<int>& fold_of_scan, int held_fold, double prior) {
  sensor::ReturnCounts counts(layout.rows(), pgm::class_count());
  for (const auto& c : ref) {
    if (held_fold >= 0 && c.scan < static_cast<int>(fold_of_scan.size()) && fold_of_scan[c.scan] == held_fold) continue;
    counts.add(c.row, c.range, c.class_id, c.returned);
  }
  return sensor::ReturnModel::fit(counts, layout, prior);
}

}  // namespace

const std::vector<std::string>& return_loop_features() {
  static const std::vector<std::string> f = {"laser", "range", "class", "material", "azimuth", "height", "class x range"};
  return f;
}

double mean_deviance(const std::vector<ReturnCell>& target, const std::vector<float>& p) {
  double d = 0;
  for (std::size_t i = 0; i < target.size(); ++i) d += bernoulli_deviance(target[i].returned, p[i]);
  return target.empty() ? 0 : d / target.size();
}

namespace {

// The target's scans, their groups and the fold of each scan (whole groups per fold); the
// target's cell and return counts.
void assign_folds(const std::vector<ReturnCell>& target, const std::vector<ReturnCell>& reference,
                  const ReturnLoopOptions& o, ReturnLoopResult& r) {
  int max_scan = 0;
  for (const auto& c : target) max_scan = std::max(max_scan, c.scan);
  for (const auto& c : reference) max_scan = std::max(max_scan, c.scan);
  std::vector<int> scans;
  {
    std::vector<char> seen(max_scan + 1, 0);
    for (const auto& c : target)
      if (!seen[c.scan]) seen[c.scan] = 1, scans.push_back(c.scan);
    std::sort(scans.begin(), scans.end());
  }
  auto group = [&](int scan) { return scan < static_cast<int>(o.scan_group.size()) ? o.scan_group[scan] : -1 - scan; };
  std::vector<int> groups;
  for (int s : scans) groups.push_back(group(s));
  std::sort(groups.begin(), groups.end());
  groups.erase(std::unique(groups.begin(), groups.end()), groups.end());
  if (groups.size() < 2) throw Error("return loop: the target needs at least 2 scans or groups of scans (folds are whole ones), got " +
                                     std::to_string(groups.size()));
  r.scans = static_cast<int>(scans.size());
  r.groups = static_cast<int>(groups.size());
  r.folds = std::min<int>(std::max(2, o.folds), r.groups);
  r.fold_of_scan.assign(max_scan + 1, -1);
  std::vector<int> position(groups.size());
  for (std::size_t k = 0; k < groups.size(); ++k) position[k] = static_cast<int>(k);
  if (o.fold_seed) {
    SplitMix shuffle(o.fold_seed);
    for (std::size_t k = groups.size(); k > 1; --k) std::swap(position[k - 1], position[shuffle.next() % k]);
  }
  for (int s : scans)
    r.fold_of_scan[s] = position[std::lower_bound(groups.begin(), groups.end(), group(s)) - groups.begin()] % r.folds;
  r.cells = static_cast<long long>(target.size());
  for (const auto& c : target) r.returns += c.returned;
}

// Sums per key of every candidate key over `cells` for which `use(i)`, with the base's p.
template <class P, class Use>
std::vector<Sums> key_sums(const std::vector<ReturnCell>& cells, int rows, P&& probability, Use&& use) {
  std::vector<Sums> sums;
  for (int k = 0; k < kKeys; ++k) sums.emplace_back(key_size(static_cast<Key>(k), rows));
  for (std::size_t i = 0; i < cells.size(); ++i) {
    const double p = probability(i);
    if (!use(i)) continue;
    for (int k = 0; k < kKeys; ++k) {
      const int key = key_of(static_cast<Key>(k), cells[i]);
      sums[k].n[key] += 1, sums[k].y[key] += cells[i].returned, sums[k].p[key] += p;
    }
  }
  return sums;
}

// Per candidate, each target cell's probability predicted from the other folds (the base of the
// fold without the cell's scan, times the candidate's multipliers fitted on the fit folds);
// r.p_before gets the base's held-out probability.
std::vector<std::vector<float>> held_out_predictions(const std::vector<ReturnCell>& target,
                                                     const std::vector<ReturnCell>& reference,
                                                     const pgm::BeamLayout& layout, const ReturnLoopOptions& o,
                                                     ReturnLoopResult& r) {
  const auto& S = specs();
  const int nc = static_cast<int>(S.size());
  r.p_before.assign(target.size(), 1.f);
  std::vector<std::vector<float>> p_cand(nc, std::vector<float>(target.size(), 1.f));
  std::vector<float> base_p(target.size());
  for (int f = 0; f < r.folds; ++f) {
    const sensor::ReturnModel base = fit_base(reference, layout, r.fold_of_scan, f, o.prior);
    auto held = [&](std::size_t i) { return r.fold_of_scan[target[i].scan] == f; };
    const std::vector<Sums> sums = key_sums(
        target, layout.rows(),
        [&](std::size_t i) {
          const auto& c = target[i];
          return base_p[i] = base.probability(c.row, c.range, c.class_id);
        },
        [&](std::size_t i) { return !held(i); });
    for (int j = 0; j < nc; ++j) {
      const auto m = fit_multipliers(S[j], sums[static_cast<int>(S[j].key)], o.shrink, nullptr);
      for (std::size_t i = 0; i < target.size(); ++i)
        if (held(i)) p_cand[j][i] = static_cast<float>(std::clamp(m[key_of(S[j].key, target[i])] * base_p[i], kEps, 1 - kEps));
    }
    for (std::size_t i = 0; i < target.size(); ++i)
      if (held(i)) r.p_before[i] = base_p[i];
  }
  return p_cand;
}

// Held-out deviance summed per bootstrap block (sector_columns-wide sectors of each scan): the
// base's, and each candidate's.
struct BlockDeviance {
  std::vector<double> base;
  std::vector<std::vector<double>> candidate;
};

BlockDeviance block_deviance(const std::vector<ReturnCell>& target, const std::vector<float>& p_before,
                             const std::vector<std::vector<float>>& p_cand, int columns, int sector_columns) {
  const int sectors = (columns + sector_columns - 1) / sector_columns;
  std::map<long long, int> block_index;
  std::vector<int> block_of(target.size());
  for (std::size_t i = 0; i < target.size(); ++i) {
    const long long key = static_cast<long long>(target[i].scan) * sectors + target[i].col / sector_columns;
    block_of[i] = block_index.try_emplace(key, static_cast<int>(block_index.size())).first->second;
  }
  const int B = static_cast<int>(block_index.size());
  BlockDeviance d{std::vector<double>(B, 0.0), std::vector<std::vector<double>>(p_cand.size(), std::vector<double>(B, 0.0))};
  for (std::size_t i = 0; i < target.size(); ++i) {
    d.base[block_of[i]] += bernoulli_deviance(target[i].returned, p_before[i]);
    for (std::size_t j = 0; j < p_cand.size(); ++j) d.candidate[j][block_of[i]] += bernoulli_deviance(target[i].returned, p_cand[j][i]);
  }
  return d;
}

// Each candidate's score 1 - D(candidate) / D(base) and its bootstrap standard error; the family's
// single-step max-T critical value (the same resampled blocks for every candidate) into r.critical.
void score_candidates(const BlockDeviance& d, const ReturnLoopOptions& o, std::vector<double>& score,
                      std::vector<double>& se, ReturnLoopResult& r) {
  MaxTScores m = block_max_t(d.base, d.candidate, o.replicates, o.level, o.seed);
  score = std::move(m.score);
  se = std::move(m.se);
  r.critical = m.critical;
}

// The decision on the candidate ranked k (0 = best) and why, in words a user reads.
void decide(ReturnCandidate& c, std::size_t k, const ReturnLoopOptions& o, ReturnLoopResult& r) {
  auto pct = [](double v) { return std::to_string(std::lround(v * 10000) / 100.0).substr(0, 5) + " %"; };
  const bool clears = c.selection_lower > 0 && c.score >= o.min_gain;
  c.decision = "not added";
  if (k == 0 && clears) {
    c.decision = "added";
    c.reason = "the best held-out deviance cut (" + pct(c.score) + "), above 0 with the family's selection-aware bound (" +
               pct(c.selection_lower) + ")";
    r.added = 0;
    r.added_feature = c.feature;
  } else if (k > 0 && clears) {
    c.reason = "one effect is added per run, the best first (" + r.candidates[0].feature + " " + to_string(r.candidates[0].form) +
               " cut more); rerun on the corrected model to judge it";
  } else if (c.score <= 0) {
    c.reason = "it does not cut the held-out deviance (" + pct(c.score) + "): fitted on the fit scans, it does not carry to the held-out ones";
  } else if (c.score < o.min_gain) {
    c.reason = "its held-out cut " + pct(c.score) + " is below the smallest cut worth adding (" + pct(o.min_gain) + ")";
  } else {
    c.reason = "the data cannot decide: its cut " + pct(c.score) + " is within what the best of " +
               std::to_string(specs().size()) + " candidates reaches by chance (bound " + pct(c.selection_lower) + ", " +
               std::to_string(r.groups) + " scan groups in " + std::to_string(r.folds) + " folds)";
  }
}

// The candidates ranked by score, each fitted once more on all target cells against the base on
// all reference cells (what is reported and what the model gains when it is added), and decided.
// Returns the ranking (indices into specs()).
std::vector<int> rank_candidates(const std::vector<ReturnCell>& target, const pgm::BeamLayout& layout,
                                 const std::vector<double>& score, const std::vector<double>& se,
                                 const ReturnLoopOptions& o, ReturnLoopResult& r) {
  const auto& S = specs();
  const int nc = static_cast<int>(S.size());
  const std::vector<Sums> all = key_sums(
      target, layout.rows(),
      [&](std::size_t i) { return r.model.probability(target[i].row, target[i].range, target[i].class_id); },
      [](std::size_t) { return true; });
  std::vector<int> order(nc);
  for (int j = 0; j < nc; ++j) order[j] = j;
  std::sort(order.begin(), order.end(), [&](int a, int b) { return score[a] > score[b]; });
  for (int j : order) {
    ReturnCandidate c;
    c.feature = S[j].feature, c.form = S[j].form;
    c.score = score[j], c.se = se[j];
    c.lower = score[j] - 1.96 * se[j], c.upper = score[j] + 1.96 * se[j];
    c.selection_lower = score[j] - r.critical * se[j];
    const auto m = fit_multipliers(S[j], all[static_cast<int>(S[j].key)], o.shrink, &c.fitted);
    c.key = S[j].key;
    c.factor.assign(m.begin(), m.end());
    r.candidates.push_back(std::move(c));
  }
  for (std::size_t k = 0; k < r.candidates.size(); ++k) decide(r.candidates[k], k, o, r);
  return order;
}

}  // namespace

ReturnLoopResult loop_returns(const std::vector<ReturnCell>& target, const std::vector<ReturnCell>& reference,
                              const pgm::BeamLayout& layout, const ReturnLoopOptions& o) {
  if (reference.empty()) throw Error("return loop: no reference cells to fit the base on");
  ReturnLoopResult r;
  assign_folds(target, reference, o, r);
  const std::vector<std::vector<float>> p_cand = held_out_predictions(target, reference, layout, o, r);
  const BlockDeviance blocks = block_deviance(target, r.p_before, p_cand, layout.columns, o.sector_columns);
  r.deviance_before = mean_deviance(target, r.p_before);
  std::vector<double> score, se;
  score_candidates(blocks, o, score, se, r);
  r.model = fit_base(reference, layout, r.fold_of_scan, -1, o.prior);
  const std::vector<int> order = rank_candidates(target, layout, score, se, o, r);
  if (r.added >= 0) {
    r.p_after = p_cand[order[0]];
    const ReturnCandidate& c = r.candidates[0];
    r.model.multipliers.push_back({c.key, c.factor, "loop returns: " + c.feature + " " + to_string(c.form) + ", held-out deviance cut " +
                                                         std::to_string(c.score)});
  } else {
    r.p_after = r.p_before;
  }
  r.deviance_after = mean_deviance(target, r.p_after);
  return r;
}

json to_json(const ReturnLoopResult& r) {
  json j;
  j["metric"] = "held-out Bernoulli deviance per geometry cell (returned or not), folds = whole scans";
  j["scans"] = r.scans, j["fold_groups"] = r.groups, j["folds"] = r.folds, j["cells"] = r.cells, j["returns"] = r.returns;
  j["deviance_before"] = r.deviance_before, j["deviance_after"] = r.deviance_after;
  j["added_effect"] = r.added_feature;
  j["selection_critical"] = r.critical;
  j["candidates"] = json::array();
  for (const auto& c : r.candidates)
    j["candidates"].push_back({{"feature", c.feature}, {"form", to_string(c.form)}, {"score", c.score}, {"se", c.se},
                               {"interval", {c.lower, c.upper}}, {"selection_lower", c.selection_lower},
                               {"decision", c.decision}, {"reason", c.reason}, {"fitted", c.fitted}});
  if (r.added >= 0) j["added"] = j["candidates"][r.added];
  return j;
}

std::string to_markdown(const ReturnLoopResult& r, const std::string& command) {
  auto f4 = [](double v) {
    char b[32];
    std::snprintf(b, sizeof b, "%.4f", v);
    return std::string(b);
  };
  std::string md = "# Closed loop: returns\n\nCommand: `" + command +
                   "`\n\nMetric: held-out Bernoulli deviance per geometry cell (returned or not); folds are whole scans (" +
                   std::to_string(r.scans) + " scans in " + std::to_string(r.groups) + " groups, " + std::to_string(r.folds) + " folds, " + std::to_string(r.cells) +
                   " cells, return rate " + f4(r.cells ? static_cast<double>(r.returns) / r.cells : 0) + ").\n\n" +
                   "Deviance before " + f4(r.deviance_before) + ", after " + f4(r.deviance_after) + "; added: " +
                   (r.added_feature.empty() ? "nothing" : r.added_feature) + ". Selection-aware critical value " +
                   f4(r.critical) + ".\n\n| feature | form | held-out cut | 95 % interval | selection bound | decision | reason |\n|---|---|---|---|---|---|---|\n";
  for (const auto& c : r.candidates)
    md += "| " + c.feature + " | " + to_string(c.form) + " | " + f4(c.score) + " | " + f4(c.lower) + " – " + f4(c.upper) + " | " +
          f4(c.selection_lower) + " | " + c.decision + " | " + c.reason + " |\n";
  return md;
}

}  // namespace lidarsim::qualify
