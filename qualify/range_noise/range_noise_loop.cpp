// The closed loop on range noise: log-scale of local-fit residuals, rotated azimuth folds with
// guard bands, candidate spread terms, the max-T bound (range_noise_loop.h says what and why).
#include "qualify/range_noise/range_noise_loop.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include "common/error.h"
#include "pgm/materials.h"
#include "qualify/returns/max_t.h"

namespace lidarsim::qualify {

using nlohmann::json;

std::vector<LoopResidual> loop_residuals(const std::vector<pgm::Point>& points, const pgm::BeamLayout& layout, int scan,
                                         const std::string& source) {
  std::vector<LoopResidual> out;
  for (const auto& r : scan_range_residuals(points, layout, RangeFitOptions{}, source)) out.push_back({scan, r});
  return out;
}

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr int kRangeBins = 24;      // 5 m each, the model's table
constexpr double kFloor = 1e-5;     // m: |e| below this reads as this (log of 0)
constexpr double kMinWindow = 200;  // residuals a window needs

// A feature binned for a table or a window.
enum class Kind { Laser, Range, Class, Material, Azimuth, Incidence, Intensity };

Kind kind_of(const std::string& name) {
  static const std::vector<std::string> names = {"laser", "range", "class", "material", "azimuth", "incidence", "intensity"};
  const auto it = std::find(names.begin(), names.end(), name);
  if (it == names.end())
    throw Error("range-noise loop: unknown feature \"" + name + "\" (laser, range, class, material, azimuth, incidence, intensity)");
  return static_cast<Kind>(it - names.begin());
}

struct Feature {
  std::string name;
  double width = 1;
  int bins = 1;
  bool circular = false;
  Kind kind = kind_of(name);
  int bin(const RangeResidual& r) const {
    double v = 0;
    switch (kind) {
      case Kind::Laser: v = r.row; break;
      case Kind::Range: v = r.range; break;
      case Kind::Class: v = r.class_id; break;
      case Kind::Material: v = r.material; break;
      case Kind::Azimuth: v = r.azimuth_deg; break;
      case Kind::Incidence: v = r.incidence * (180 / 3.14159265358979323846); break;
      case Kind::Intensity: v = r.intensity; break;
    }
    if (!std::isfinite(v)) return -1;
    const long k = static_cast<long>(std::floor(v / width));
    return static_cast<int>(circular ? ((k % bins) + bins) % bins : std::clamp(k, 0L, static_cast<long>(bins) - 1));
  }
};

struct Spec {
  Feature feature;
  TermForm form;  // growth: range only (qualify/returns/term_form.h)
};

double log_abs(float e) { return std::log(std::max<double>(std::abs(e), kFloor)); }
// What the loop models: log|e| less the residual's own predicted log-scale (LoopResidual::offset).
double log_scale_of(const LoopResidual& x) { return log_abs(x.r.residual) - x.offset; }

// The features, their bin widths from the data where the scale is the sensor's (intensity: 20
// bins up to the 99th percentile) and the row count.
Feature feature_named(const std::string& name, const std::vector<LoopResidual>& data, bool window) {
  if (name == "laser") {
    int rows = 1;
    for (const auto& x : data) rows = std::max(rows, x.r.row + 1);
    return {name, 1, rows, false};
  }
  if (name == "range") return {name, 5, kRangeBins, false};
  if (name == "class") return {name, 1, pgm::class_count(), false};
  if (name == "material") return {name, 1, pgm::material_count(), false};
  if (name == "azimuth") return window ? Feature{name, 5, 72, true} : Feature{name, 10, 36, true};
  if (name == "incidence") return {name, 10, 9, false};
  if (name == "intensity") {
    std::vector<float> v;
    for (const auto& x : data)
      if (std::isfinite(x.r.intensity)) v.push_back(x.r.intensity);
    double top = 1;
    if (!v.empty()) {
      const std::size_t k = v.size() * 99 / 100;
      std::nth_element(v.begin(), v.begin() + k, v.end());
      if (v[k] > 0) top = v[k];
    }
    return {name, top / 20, 20, false};
  }
  throw Error("range-noise loop: unknown feature \"" + name + "\" (laser, range, class, material, azimuth, incidence, intensity)");
}

std::vector<Spec> specs_of(const std::vector<LoopResidual>& target) {
  std::vector<Spec> s;
  for (const char* name : {"laser", "range", "class", "material", "azimuth", "incidence", "intensity"}) {
    s.push_back({feature_named(name, target, false), TermForm::table});
    const std::string n = name;
    if (n != "class" && n != "material") s.push_back({feature_named(name, target, true), TermForm::window});
    if (n == "range") s.push_back({feature_named(name, target, false), TermForm::growth});
  }
  return s;
}

// Per feature bin: the sum of d and the count over the residuals used.
struct BinSums {
  std::vector<double> s, n;
};

// A candidate's shift per bin from the fit residuals' sums (0 = no change).
std::vector<double> fit_shifts(const Spec& spec, const BinSums& b, double shrink, json* fitted) {
  const int K = spec.feature.bins;
  std::vector<double> t(K, 0.0);
  if (spec.form == TermForm::table) {
    for (int k = 0; k < K; ++k) t[k] = b.s[k] / (b.n[k] + shrink);
    if (fitted) *fitted = {{"bins", K}, {"width", spec.feature.width}, {"residuals", b.n}};
    return t;
  }
  double best = 0, shift = 0;
  int ba = -1, bb = -1;
  for (int a = 0; a < K; ++a) {
    double s = 0, n = 0;
    for (int len = 1; len < K; ++len) {  // never every bin: that is a global level
      const int e = a + len - 1;
      if (!spec.feature.circular && e >= K) break;
      s += b.s[e % K], n += b.n[e % K];
      if (n < kMinWindow) continue;
      const double g = s * s / (n + shrink);
      if (g > best) best = g, ba = a, bb = e, shift = s / (n + shrink);
    }
  }
  if (ba >= 0)
    for (int e = ba; e <= bb; ++e) t[e % K] = shift;
  if (fitted)
    *fitted = {{"bins", K}, {"width", spec.feature.width}, {"first_bin", ba}, {"last_bin", ba >= 0 ? bb % K : -1},
               {"factor", std::exp(shift)}};
  return t;
}

// The growth form: a spread c r added in quadrature to the base's, whose Gaussian-equivalent
// spread is exp(b + 0.635); on the log scale the prediction moves by 0.5 log(1 + (c r)^2 / s^2).
constexpr double kGaussLogScale = -0.6351814;  // E log|Z| for a standard normal Z

double growth_shift(double c, double q) { return 0.5 * std::log1p(c * c * q); }  // q = r^2 / s^2


// c minimising sum (d - growth_shift(c, q))^2: a log grid over 1e-5..0.05 m/m (and 0), refined
// by golden section around the best grid point.
double fit_growth(const std::vector<double>& d, const std::vector<double>& q) {
  auto sse = [&](double c) {
    double e = 0;
    for (std::size_t i = 0; i < d.size(); ++i) e += std::pow(d[i] - growth_shift(c, q[i]), 2);
    return e;
  };
  std::vector<double> grid = {0};
  for (int k = 0; k <= 24; ++k) grid.push_back(1e-5 * std::pow(5000.0, k / 24.0));
  std::size_t best = 0;
  double best_e = sse(0);
  for (std::size_t k = 1; k < grid.size(); ++k)
    if (const double e = sse(grid[k]); e < best_e) best_e = e, best = k;
  if (best == 0) return 0;
  double lo = grid[best - 1], hi = grid[std::min(best + 1, grid.size() - 1)];
  const double g = 0.6180339887;
  double a = hi - g * (hi - lo), b = lo + g * (hi - lo), ea = sse(a), eb = sse(b);
  for (int it = 0; it < 14; ++it) {
    if (ea < eb) hi = b, b = a, eb = ea, a = hi - g * (hi - lo), ea = sse(a);
    else lo = a, a = b, ea = eb, b = lo + g * (hi - lo), eb = sse(b);
  }
  return 0.5 * (lo + hi);
}

// Residuals with what the base reads precomputed: y = log|e|, the range, and the bins of the range
// level and of every base term (bins[0] = range, bins[1 + t] = term t).
struct Data {
  std::vector<double> y, range;
  std::vector<std::vector<int>> bins;
};

Data data_of(const std::vector<LoopResidual>& x, const std::vector<Feature>& features) {
  Data d;
  d.bins.assign(features.size(), std::vector<int>(x.size()));
  for (std::size_t i = 0; i < x.size(); ++i) {
    d.y.push_back(log_scale_of(x[i]));
    d.range.push_back(x[i].r.range);
    for (std::size_t f = 0; f < features.size(); ++f) d.bins[f][i] = features[f].bin(x[i].r);
  }
  return d;
}

double growth_q_of(double range, double b) {
  const double s = std::exp(b - kGaussLogScale);
  return range * range / (s * s);
}

// The base: a log-scale per range bin plus a shift table per base term, fitted by backfitting.
struct Base {
  std::vector<std::vector<double>> table;  // [0]: level per range bin; [1 + t]: term t's shift per bin
  double growth_c = 0;                     // a growth term (fitted after the tables)
  double tables(const Data& x, std::size_t i) const {
    double b = 0;
    for (std::size_t t = 0; t < table.size(); ++t)
      if (const int k = x.bins[t][i]; k >= 0) b += table[t][k];
    return b;
  }
  double predict(const Data& x, std::size_t i) const {
    const double b = tables(x, i);
    return growth_c > 0 ? b + growth_shift(growth_c, growth_q_of(x.range[i], b)) : b;
  }
};

// features[0] is the range level (shrunk towards the mean log-scale), the others are terms
// (shrunk towards 0).
template <class Use>
Base fit_base(const Data& ref, const std::vector<Feature>& features, bool growth, double shrink, Use&& use) {
  Base base;
  for (const auto& f : features) base.table.emplace_back(f.bins, 0.0);
  double all = 0, count = 0;
  for (std::size_t i = 0; i < ref.y.size(); ++i)
    if (use(i)) all += ref.y[i], ++count;
  if (count == 0) throw Error("range-noise loop: no reference residual to fit the base on in a fold");
  all /= count;
  std::vector<double> fit(ref.y.size(), 0.0);  // the tables' current prediction
  for (int iter = 0; iter < (features.size() == 1 ? 1 : 4); ++iter) {
    for (std::size_t t = 0; t < features.size(); ++t) {
      const double centre = t == 0 ? all : 0;
      std::vector<double> s(features[t].bins, 0.0), n(features[t].bins, 0.0);
      for (std::size_t i = 0; i < ref.y.size(); ++i) {
        const int k = ref.bins[t][i];
        if (!use(i) || k < 0) continue;
        s[k] += ref.y[i] - fit[i] + base.table[t][k] - centre;
        n[k] += 1;
      }
      std::vector<double> next(features[t].bins);
      for (int k = 0; k < features[t].bins; ++k) next[k] = centre + s[k] / (n[k] + shrink);
      for (std::size_t i = 0; i < ref.y.size(); ++i)
        if (const int k = ref.bins[t][i]; k >= 0) fit[i] += next[k] - base.table[t][k];
      base.table[t] = std::move(next);
    }
  }
  if (growth) {  // the tables first, then c on what they leave (the tables are not refitted after it)
    std::vector<double> d, q;
    for (std::size_t i = 0; i < ref.y.size(); ++i)
      if (use(i)) d.push_back(ref.y[i] - fit[i]), q.push_back(growth_q_of(ref.range[i], fit[i]));
    base.growth_c = fit_growth(d, q);
  }
  return base;
}

// Which fold a residual belongs to and, when it lies within the guard of a boundary with another
// fold's sector, that fold (else -1).
struct FoldOf {
  int fold = 0, near = -1, block = 0;
};

FoldOf fold_of(const LoopResidual& x, const RangeLoopOptions& o) {
  const double w = 360.0 / o.sectors;
  double a = std::fmod(x.r.azimuth_deg - o.rotation_deg, 360.0);
  if (a < 0) a += 360;
  const int s = std::min(o.sectors - 1, static_cast<int>(a / w));
  const double u = a - s * w;
  FoldOf f;
  f.fold = s % o.folds;
  if (u < o.guard_deg) f.near = ((s + o.sectors - 1) % o.sectors) % o.folds;
  else if (u > w - o.guard_deg) f.near = ((s + 1) % o.sectors) % o.folds;
  if (f.near == f.fold) f.near = -1;
  f.block = x.scan * o.sectors + s;
  return f;
}

bool fitted_in(const FoldOf& f, int fold) { return f.fold != fold && f.near != fold; }
bool scored_in(const FoldOf& f, int fold) { return f.fold == fold && f.near < 0; }

// Held-out predictions of every candidate (log-scales, per target residual; NaN where not scored)
// and the base's into r.b_before.
std::vector<std::vector<float>> held_out(const std::vector<LoopResidual>& target, const std::vector<LoopResidual>& ref,
                                         const std::vector<Spec>& specs, const std::vector<Feature>& base_features,
                                         bool growth, const RangeLoopOptions& o, RangeLoopResult& r) {
  std::vector<FoldOf> ft(target.size()), fr(ref.size());
  for (std::size_t i = 0; i < target.size(); ++i) ft[i] = fold_of(target[i], o);
  for (std::size_t i = 0; i < ref.size(); ++i) fr[i] = fold_of(ref[i], o);
  r.fold.resize(target.size());
  for (std::size_t i = 0; i < target.size(); ++i) r.fold[i] = ft[i].near < 0 ? ft[i].fold : -1;
  r.b_before.assign(target.size(), static_cast<float>(kNaN));
  const Data dr = data_of(ref, base_features), dt = data_of(target, base_features);
  std::vector<std::vector<int>> spec_bins(specs.size(), std::vector<int>(target.size()));
  for (std::size_t j = 0; j < specs.size(); ++j)
    for (std::size_t i = 0; i < target.size(); ++i) spec_bins[j][i] = specs[j].feature.bin(target[i].r);
  std::vector<std::vector<float>> pred(specs.size(), std::vector<float>(target.size(), static_cast<float>(kNaN)));
  std::vector<double> b(target.size());
  for (int f = 0; f < o.folds; ++f) {
    const Base base = fit_base(dr, base_features, growth, o.shrink, [&](std::size_t i) { return fitted_in(fr[i], f); });
    for (std::size_t i = 0; i < target.size(); ++i) b[i] = base.predict(dt, i);
    for (std::size_t j = 0; j < specs.size(); ++j) {
      if (specs[j].form == TermForm::growth) {
        std::vector<double> d, q;
        for (std::size_t i = 0; i < target.size(); ++i)
          if (fitted_in(ft[i], f)) d.push_back(dt.y[i] - b[i]), q.push_back(growth_q_of(dt.range[i], b[i]));
        const double c = fit_growth(d, q);
        for (std::size_t i = 0; i < target.size(); ++i)
          if (scored_in(ft[i], f)) pred[j][i] = static_cast<float>(b[i] + growth_shift(c, growth_q_of(dt.range[i], b[i])));
        continue;
      }
      const int K = specs[j].feature.bins;
      BinSums sums{std::vector<double>(K, 0.0), std::vector<double>(K, 0.0)};
      for (std::size_t i = 0; i < target.size(); ++i)
        if (const int k = spec_bins[j][i]; k >= 0 && fitted_in(ft[i], f)) sums.s[k] += dt.y[i] - b[i], sums.n[k] += 1;
      const std::vector<double> t = fit_shifts(specs[j], sums, o.shrink, nullptr);
      for (std::size_t i = 0; i < target.size(); ++i)
        if (scored_in(ft[i], f)) pred[j][i] = static_cast<float>(b[i] + (spec_bins[j][i] >= 0 ? t[spec_bins[j][i]] : 0.0));
    }
    for (std::size_t i = 0; i < target.size(); ++i)
      if (scored_in(ft[i], f)) r.b_before[i] = static_cast<float>(b[i]);
  }
  return pred;
}

// The squared log-scale errors summed per block (a scan's sector) of the scored residuals: the
// base's and each candidate's, for the max-T bootstrap; counts the scored residuals into r.scored.
void block_losses(const std::vector<LoopResidual>& target, const std::vector<std::vector<float>>& pred,
                  const RangeLoopOptions& o, RangeLoopResult& r, std::vector<double>& base_loss,
                  std::vector<std::vector<double>>& cand_loss) {
  int max_scan = 0;
  for (const auto& x : target) max_scan = std::max(max_scan, x.scan);
  std::vector<int> block_of(target.size(), -1), index(static_cast<std::size_t>(max_scan + 1) * o.sectors, -1);
  int B = 0;
  for (std::size_t i = 0; i < target.size(); ++i) {
    if (!std::isfinite(r.b_before[i])) continue;
    const int k = fold_of(target[i], o).block;
    if (index[k] < 0) index[k] = B++;
    block_of[i] = index[k];
    ++r.scored;
  }
  base_loss.assign(B, 0.0);
  cand_loss.assign(pred.size(), std::vector<double>(B, 0.0));
  for (std::size_t i = 0; i < target.size(); ++i) {
    if (block_of[i] < 0) continue;
    const double y = log_scale_of(target[i]);
    base_loss[block_of[i]] += (y - r.b_before[i]) * (y - r.b_before[i]);
    for (std::size_t j = 0; j < pred.size(); ++j) cand_loss[j][block_of[i]] += (y - pred[j][i]) * (y - pred[j][i]);
  }
}

void decide(RangeCandidate& c, std::size_t k, std::size_t family, const RangeLoopOptions& o, RangeLoopResult& r) {
  auto pct = [](double v) { return std::to_string(std::lround(v * 10000) / 100.0).substr(0, 5) + " %"; };
  const bool clears = c.selection_lower > 0 && c.score >= o.min_gain;
  c.decision = "not added";
  if (k == 0 && clears) {
    c.decision = "added";
    c.reason = "the best held-out cut of the log-scale error (" + pct(c.score) +
               "), above 0 with the family's selection-aware bound (" + pct(c.selection_lower) + ")";
    r.added = 0;
    r.added_feature = c.feature;
  } else if (k > 0 && clears) {
    c.reason = "one term is added per run, the best first (" + r.candidates[0].feature + " " + to_string(r.candidates[0].form) +
               " cut more); rerun with it in the base (--rounds) to judge this one";
  } else if (c.score <= 0) {
    c.reason = "it does not cut the held-out error (" + pct(c.score) + "): fitted on the other sectors, it does not carry";
  } else if (c.score < o.min_gain) {
    c.reason = "its held-out cut " + pct(c.score) + " is below the smallest cut worth adding (" + pct(o.min_gain) + ")";
  } else {
    c.reason = "the data cannot decide: its cut " + pct(c.score) + " is within what the best of " + std::to_string(family) +
               " candidates reaches by chance (bound " + pct(c.selection_lower) + ", " + std::to_string(r.scans) +
               " scans in " + std::to_string(o.folds) + " azimuth folds)";
  }
}

// The written model: the range table (1.4826 MAD per 5 m bin with >= 200 residuals) of the
// residuals divided by every term's factor, so that sigma(r) x the factors is each residual's spread.
sensor::RangeNoiseModel model_of(const std::vector<LoopResidual>& target, std::vector<sensor::RangeNoiseTerm> terms,
                                 double extra_per_m) {
  sensor::RangeNoiseModel m;
  m.terms = std::move(terms);
  std::vector<RangeResidual> scaled;
  for (const auto& x : target) {
    sensor::RangeNoiseFeatures f;
    f.range_m = x.r.range, f.row = x.r.row, f.class_id = x.r.class_id, f.material = x.r.material;
    f.azimuth_deg = x.r.azimuth_deg, f.incidence_rad = x.r.incidence, f.intensity = x.r.intensity;
    double factor = 1;
    for (const auto& t : m.terms) factor *= t.factor_at(f);
    RangeResidual s = x.r;
    s.residual = static_cast<float>(x.r.residual / factor);
    scaled.push_back(s);
  }
  std::vector<double> edges;
  for (int k = 0; k <= kRangeBins; ++k) edges.push_back(5.0 * k);
  const auto bins = spread_by(scaled, [](const RangeResidual& x) { return x.range; }, edges);
  // With a growth term the table holds what is left after it: sigma^2 - (c r)^2 (at least 10 % of sigma).
  auto rest = [&](double sigma, double r) {
    return std::sqrt(std::max(0.01 * sigma * sigma, sigma * sigma - std::pow(extra_per_m * r, 2)));
  };
  std::vector<SpreadBin> rest_bins = bins;
  for (auto& b : rest_bins) b.sigma = rest(b.sigma, b.mean);
  const SigmaFit fit = fit_sigma_of_range(rest_bins);
  m.a = fit.a, m.b = fit.b;
  m.extra_per_m = extra_per_m;
  for (const auto& b : rest_bins)
    if (b.n >= 200) m.table_range_m.push_back(b.mean), m.table_sigma_m.push_back(b.sigma);
  m.validate("range-noise loop model");
  return m;
}

sensor::RangeNoiseTerm term_of(const Feature& f, const std::vector<double>& shift, const std::string& note) {
  sensor::RangeNoiseTerm t;
  t.feature = f.name, t.width = f.width, t.note = note;
  for (double s : shift) t.factor.push_back(std::exp(s));
  return t;
}

}  // namespace

std::string base_term_name(const RangeCandidate& c) { return c.form == TermForm::growth ? c.feature + " growth" : c.feature; }

double log_scale_error(const std::vector<LoopResidual>& target, const std::vector<float>& b) {
  double e = 0;
  long long n = 0;
  for (std::size_t i = 0; i < target.size(); ++i)
    if (std::isfinite(b[i])) e += std::pow(log_scale_of(target[i]) - b[i], 2), ++n;
  return n ? e / n : 0;
}

RangeLoopResult loop_range_noise(const std::vector<LoopResidual>& target, const std::vector<LoopResidual>& reference,
                                 const RangeLoopOptions& o) {
  if (target.empty() || reference.empty()) throw Error("range-noise loop: no residuals in the target or the reference");
  if (o.folds < 2 || o.sectors < o.folds || o.sectors % o.folds)
    throw Error("range-noise loop: sectors must be a multiple of folds >= 2");
  RangeLoopResult r;
  r.folds = o.folds;
  r.residuals = static_cast<long long>(target.size());
  {
    std::vector<int> scans;
    for (const auto& x : target) scans.push_back(x.scan);
    std::sort(scans.begin(), scans.end());
    r.scans = static_cast<int>(std::unique(scans.begin(), scans.end()) - scans.begin());
  }
  std::vector<Feature> base_features = {feature_named("range", target, false)};  // [0]: the range level
  bool growth = false;
  for (const auto& n : o.base_terms) {
    if (n == "range growth") growth = true;
    else base_features.push_back(feature_named(n, target, false));
  }
  const std::vector<Spec> specs = specs_of(target);
  const auto pred = held_out(target, reference, specs, base_features, growth, o, r);
  std::vector<double> base_loss;
  std::vector<std::vector<double>> cand_loss;
  block_losses(target, pred, o, r, base_loss, cand_loss);
  const MaxTScores m = block_max_t(base_loss, cand_loss, o.replicates, o.level, o.seed);
  r.critical = m.critical;
  r.error_before = log_scale_error(target, r.b_before);
  // Every candidate fitted once more on every target residual against the base on every reference one.
  const Data dt = data_of(target, base_features);
  const Base full = fit_base(data_of(reference, base_features), base_features, growth, o.shrink, [](std::size_t) { return true; });
  std::vector<int> order(specs.size());
  for (std::size_t j = 0; j < specs.size(); ++j) order[j] = static_cast<int>(j);
  std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return m.score[a] > m.score[b]; });
  for (int j : order) {
    RangeCandidate c;
    c.feature = specs[j].feature.name, c.form = specs[j].form;
    c.score = m.score[j], c.se = m.se[j];
    c.lower = c.score - 1.96 * c.se, c.upper = c.score + 1.96 * c.se;
    c.selection_lower = c.score - m.critical * c.se;
    const Feature& fe = specs[j].feature;
    if (specs[j].form == TermForm::growth) {
      std::vector<double> d, q;
      for (std::size_t i = 0; i < target.size(); ++i) {
        const double b = full.predict(dt, i);
        d.push_back(dt.y[i] - b), q.push_back(growth_q_of(dt.range[i], b));
      }
      c.extra_per_m = fit_growth(d, q);
      c.fitted = {{"extra_sigma_mm_per_m", 1000 * c.extra_per_m}};
    } else {
      BinSums sums{std::vector<double>(fe.bins, 0.0), std::vector<double>(fe.bins, 0.0)};
      for (std::size_t i = 0; i < target.size(); ++i)
        if (const int k = fe.bin(target[i].r); k >= 0) sums.s[k] += dt.y[i] - full.predict(dt, i), sums.n[k] += 1;
      c.term = term_of(fe, fit_shifts(specs[j], sums, o.shrink, &c.fitted), "");
    }
    r.candidates.push_back(std::move(c));
  }
  for (std::size_t k = 0; k < r.candidates.size(); ++k) decide(r.candidates[k], k, specs.size(), o, r);
  std::vector<sensor::RangeNoiseTerm> model_terms;
  double extra = full.growth_c;
  for (std::size_t t = 1; t < base_features.size(); ++t)
    model_terms.push_back(term_of(base_features[t], full.table[t], "base term"));
  if (r.added >= 0) {
    r.b_after = pred[order[0]];
    auto& c = r.candidates[0];
    c.term.note = "lidar-qualify loop range-noise: " + c.feature + " " + to_string(c.form) + ", held-out log-scale error cut " +
                  std::to_string(c.score);
    if (c.form == TermForm::growth) extra = std::hypot(extra, c.extra_per_m);
    else model_terms.push_back(c.term);
  } else {
    r.b_after = r.b_before;
  }
  r.error_after = log_scale_error(target, r.b_after);
  r.terms = model_terms;
  {
    // The range level relative to its mean over the residuals: a spread by range, not a global scale.
    double mean = 0;
    long long n = 0;
    for (std::size_t i = 0; i < target.size(); ++i)
      if (const int k = dt.bins[0][i]; k >= 0) mean += full.table[0][k], ++n;
    std::vector<double> level = full.table[0];
    for (double& v : level) v -= n ? mean / n : 0.0;
    r.range_level = term_of(base_features[0], level, "the base's log-scale per range bin relative to its mean, as a factor");
  }
  if (o.fit_range_model) r.model = model_of(target, std::move(model_terms), extra);
  return r;
}

json to_json(const RangeLoopResult& r) {
  json j;
  j["metric"] = "held-out mean (log|e| - predicted log-scale)^2 per residual; folds = rotated azimuth sectors with guard bands";
  j["scans"] = r.scans, j["folds"] = r.folds, j["residuals"] = r.residuals, j["scored"] = r.scored;
  j["error_before"] = r.error_before, j["error_after"] = r.error_after;
  j["added_effect"] = r.added_feature;
  j["selection_critical"] = r.critical;
  j["candidates"] = json::array();
  for (const auto& c : r.candidates) {
    json f = c.fitted;
    if (c.form != TermForm::growth) f["factor_per_bin"] = c.term.factor;
    j["candidates"].push_back({{"feature", c.feature}, {"form", to_string(c.form)}, {"score", c.score}, {"se", c.se},
                               {"interval", {c.lower, c.upper}}, {"selection_lower", c.selection_lower},
                               {"decision", c.decision}, {"reason", c.reason}, {"fitted", f}});
  }
  if (r.added >= 0) j["added"] = j["candidates"][r.added];
  return j;
}

std::string to_markdown(const RangeLoopResult& r, const std::string& command, const std::string& subject) {
  auto f4 = [](double v) {
    char b[32];
    std::snprintf(b, sizeof b, "%.4f", v);
    return std::string(b);
  };
  std::string md = "# Closed loop: " + subject + "\n\nCommand: `" + command +
                   "`\n\nMetric: held-out mean (log|e| - predicted log-scale)^2 per residual (a right Gaussian spread gives "
                   "1.234); folds are rotated azimuth sectors with guard bands (" + std::to_string(r.scans) + " scans, " +
                   std::to_string(r.residuals) + " residuals, " + std::to_string(r.scored) + " scored, " +
                   std::to_string(r.folds) + " folds).\n\nError before " + f4(r.error_before) + ", after " +
                   f4(r.error_after) + "; added: " + (r.added_feature.empty() ? "nothing" : r.added_feature) +
                   ". Selection-aware critical value " + f4(r.critical) +
                   ".\n\n| feature | form | held-out cut | 95 % interval | selection bound | decision | reason |\n"
                   "|---|---|---|---|---|---|---|\n";
  for (const auto& c : r.candidates)
    md += "| " + c.feature + " | " + to_string(c.form) + " | " + f4(c.score) + " | " + f4(c.lower) + " – " + f4(c.upper) + " | " +
          f4(c.selection_lower) + " | " + c.decision + " | " + c.reason + " |\n";
  return md;
}

}  // namespace lidarsim::qualify
