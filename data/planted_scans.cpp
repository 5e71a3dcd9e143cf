#include "data/planted_scans.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <random>

#include "common/angles.h"
#include "common/error.h"
#include "data/baselines.h"
#include "pgm/materials.h"

namespace lidarsim::data {
namespace {


// Portable draws: mt19937_64's output is fixed by the standard, the std:: distributions are not,
// so uniform and normal are written out here and a seed gives the same draw on every library.
class Rng {
 public:
  explicit Rng(std::uint64_t seed) : g_(seed) {}
  double uniform() { return static_cast<double>(g_() >> 11) * (1.0 / 9007199254740992.0); }
  double uniform(double a, double b) { return a + (b - a) * uniform(); }
  int integer(int lo, int hi) { return lo + static_cast<int>(std::min<double>(hi - lo, std::floor(uniform() * (hi - lo + 1)))); }
  bool coin() { return uniform() < 0.5; }
  double normal() {
    const double u1 = std::max(uniform(), 1e-300), u2 = uniform();
    return std::sqrt(-2 * std::log(u1)) * std::cos(2 * kPi * u2);
  }

 private:
  std::mt19937_64 g_;
};

std::uint64_t mix(std::uint64_t x) {  // splitmix64 finaliser: nearby seeds give unrelated streams
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}

// A gain below 1 or above 1, each side with probability 1/2.
double gain_either_side(Rng& rng, double lo_a, double lo_b, double hi_a, double hi_b) {
  return rng.coin() ? rng.uniform(lo_a, lo_b) : rng.uniform(hi_a, hi_b);
}

// Classes with at least `share` of the returns of `geometry`, unlabeled excluded.
std::vector<int> common_classes(const Dataset& geometry, double share) {
  const int ic = geometry.channel_index("class");
  const auto s = geometry.pgm.shape();
  const std::size_t plane = static_cast<std::size_t>(s.h) * s.w;
  std::vector<long> count(pgm::cls::count, 0);
  long total = 0;
  for (int n = 0; n < s.n; ++n)
    for (std::size_t k = 0; k < plane; ++k)
      if (geometry.mask.data()[n * plane + k] > 0) {
        const int c = static_cast<int>(geometry.pgm.data()[(static_cast<std::size_t>(n) * s.c + ic) * plane + k]);
        if (c > 0 && c < pgm::cls::count) ++count[c];
        ++total;
      }
  std::vector<int> out;
  for (int c = 1; c < pgm::cls::count; ++c)
    if (total > 0 && count[c] >= share * total) out.push_back(c);
  if (out.empty()) throw Error("planted scans: no labelled class has " + std::to_string(share * 100) + " % of the returns");
  return out;
}

void draw_effect(PlantedScanEffect& e, Rng& rng, const Dataset& geometry) {
  const int rows = geometry.rows();
  auto& p = e.parameters;
  switch (e.family) {
    case PlantedScanFamily::BeamGain: {
      const double spread = rng.uniform(0.1, 0.5);
      e.row_gain.resize(rows);
      for (double& g : e.row_gain) g = 1 + spread * rng.uniform(-1, 1);
      p = {{"spread", spread}, {"row_gain", e.row_gain}};
      break;
    }
    case PlantedScanFamily::BadLasers: {
      const int bad = rng.integer(2, std::min(10, rows));
      std::vector<int> order(rows);
      std::iota(order.begin(), order.end(), 0);
      for (int k = 0; k < bad; ++k) std::swap(order[k], order[rng.integer(k, rows - 1)]);  // partial shuffle
      e.row_gain.assign(rows, 1.0);
      nlohmann::json lasers = nlohmann::json::array();
      for (int k = 0; k < bad; ++k) {
        e.row_gain[order[k]] = rng.uniform(0.3, 0.8);
        lasers.push_back({{"row", order[k]}, {"gain", e.row_gain[order[k]]}});
      }
      p = {{"bad_lasers", lasers}};
      break;
    }
    case PlantedScanFamily::AzimuthWindow:
      e.azimuth_width_deg = rng.uniform(20, 120);
      e.azimuth_start_deg = rng.uniform(0, 360);
      e.gain = gain_either_side(rng, 0.4, 0.8, 1.25, 2.0);
      p = {{"start_deg", e.azimuth_start_deg}, {"width_deg", e.azimuth_width_deg}, {"gain", e.gain}};
      break;
    case PlantedScanFamily::RangeFalloff: {
      const int size = rng.integer(std::max(1, rows / 4), std::max(1, rows / 2));
      e.row_first = rng.integer(0, rows - size);
      e.row_last = e.row_first + size - 1;
      e.exponent = (rng.coin() ? 1 : -1) * rng.uniform(0.2, 0.6);
      p = {{"row_first", e.row_first}, {"row_last", e.row_last}, {"exponent", e.exponent},
           {"reference_range_m", e.reference_range_m}};
      break;
    }
    case PlantedScanFamily::IncidenceFalloff:
      e.exponent = rng.uniform(0.3, 1.2);
      p = {{"exponent", e.exponent}};
      break;
    case PlantedScanFamily::ClassGain: {
      const auto classes = common_classes(geometry, 0.02);
      e.class_id = classes[rng.integer(0, static_cast<int>(classes.size()) - 1)];
      e.gain = gain_either_side(rng, 0.5, 0.8, 1.25, 1.6);
      p = {{"class", pgm::class_name(e.class_id)}, {"gain", e.gain}};
      break;
    }
    case PlantedScanFamily::Control: p = nlohmann::json::object(); break;
  }
}

}  // namespace

const std::vector<PlantedScanFamily>& all_planted_families() {
  static const std::vector<PlantedScanFamily> all = {PlantedScanFamily::BeamGain,         PlantedScanFamily::BadLasers,
                                                 PlantedScanFamily::AzimuthWindow,    PlantedScanFamily::RangeFalloff,
                                                 PlantedScanFamily::IncidenceFalloff, PlantedScanFamily::ClassGain,
                                                 PlantedScanFamily::Control};
  return all;
}

std::string to_string(PlantedScanFamily f) {
  switch (f) {
    case PlantedScanFamily::BeamGain: return "beam_gain";
    case PlantedScanFamily::BadLasers: return "bad_lasers";
    case PlantedScanFamily::AzimuthWindow: return "azimuth_window";
    case PlantedScanFamily::RangeFalloff: return "range_falloff";
    case PlantedScanFamily::IncidenceFalloff: return "incidence_falloff";
    case PlantedScanFamily::ClassGain: return "class_gain";
    case PlantedScanFamily::Control: return "control";
  }
  return "unknown";
}

PlantedScanFamily planted_scan_family_from_string(const std::string& name) {
  std::string known;
  for (PlantedScanFamily f : all_planted_families()) {
    if (to_string(f) == name) return f;
    known += (known.empty() ? "" : ", ") + to_string(f);
  }
  throw Error("planted scans: family '" + name + "': unknown (known: " + known + ")");
}

std::string to_string(PlantedScoring s) {
  switch (s) {
    case PlantedScoring::Detect: return "detect";
    case PlantedScoring::Absorbed: return "absorbed";
    case PlantedScoring::Control: return "control";
  }
  return "unknown";
}

double HiddenIntensityBase::operator()(int class_id, double range_m) const {
  const double a = class_id >= 0 && class_id < static_cast<int>(albedo.size()) ? albedo[class_id] : albedo.at(0);
  const double r = binned ? (range_bin(range_m) + 0.5) * kRangeBinM : range_m;
  return a * std::exp(-r / attenuation_m);
}

double PlantedScanEffect::gain_at(int row, double range_m, double azimuth_rad, double incidence_rad, int cls) const {
  switch (family) {
    case PlantedScanFamily::BeamGain:
    case PlantedScanFamily::BadLasers: return row >= 0 && row < static_cast<int>(row_gain.size()) ? row_gain[row] : 1.0;
    case PlantedScanFamily::AzimuthWindow: {
      const double deg = std::fmod(azimuth_rad * 180 / kPi + 720, 360);
      return std::fmod(deg - azimuth_start_deg + 720, 360) < azimuth_width_deg ? gain : 1.0;
    }
    case PlantedScanFamily::RangeFalloff:
      // Ranges under 1 m are the sensor's own housing region: held at the 1 m gain.
      return row >= row_first && row <= row_last ? std::pow(std::max(range_m, 1.0) / reference_range_m, -exponent) : 1.0;
    case PlantedScanFamily::IncidenceFalloff: return std::pow(std::cos(std::clamp(incidence_rad, 0.0, kPi / 2)), exponent);
    case PlantedScanFamily::ClassGain: return cls == class_id ? gain : 1.0;
    case PlantedScanFamily::Control: return 1.0;
  }
  return 1.0;
}

nlohmann::json PlantedScanDraw::to_json() const {
  nlohmann::json albedo = nlohmann::json::object();
  for (int c = 0; c < static_cast<int>(base.albedo.size()); ++c) albedo[pgm::class_name(c)] = base.albedo[c];
  return {{"family", to_string(family)},
          {"seed", seed},
          {"scoring", to_string(effect.scoring)},
          {"feature", effect.feature.empty() ? nlohmann::json(nullptr) : nlohmann::json(effect.feature)},
          {"accepted", effect.accepted},
          {"parameters", effect.parameters},
          {"hidden_base", {{"albedo", albedo}, {"attenuation_m", base.attenuation_m}, {"sigma", base.sigma},
                           {"fall_off_at", base.binned ? "5 m range-bin centre" : "range"}}}};
}

PlantedScanDraw draw_planted(PlantedScanFamily family, std::uint64_t seed, const Dataset& geometry, double sigma, bool binned) {
  if (!(sigma >= 0)) throw Error("planted scans: sigma: expected >= 0, got " + std::to_string(sigma));
  PlantedScanDraw d;
  d.family = family;
  d.seed = seed;
  Rng rng(mix(seed));
  d.base.sigma = sigma;
  d.base.binned = binned;
  d.base.albedo.resize(pgm::cls::count);
  for (double& a : d.base.albedo) a = rng.uniform(0.15, 0.6);
  d.base.attenuation_m = rng.uniform(60, 150);
  PlantedScanEffect& e = d.effect;
  e.family = family;
  switch (family) {
    case PlantedScanFamily::BeamGain:
    case PlantedScanFamily::BadLasers: e.feature = "beam_row", e.accepted = {"beam_row"}; break;
    case PlantedScanFamily::RangeFalloff: e.feature = "beam_row", e.accepted = {"beam_row", "elevation"}; break;
    case PlantedScanFamily::AzimuthWindow: e.feature = "azimuth", e.accepted = {"azimuth"}; break;
    case PlantedScanFamily::IncidenceFalloff: e.feature = "incidence_angle", e.accepted = {"incidence_angle"}; break;
    case PlantedScanFamily::ClassGain:
    case PlantedScanFamily::Control: break;
  }
  e.scoring = family == PlantedScanFamily::Control     ? PlantedScoring::Control
              : family == PlantedScanFamily::ClassGain ? PlantedScoring::Absorbed
                                                   : PlantedScoring::Detect;
  draw_effect(e, rng, geometry);
  return d;
}

Dataset plant(const Dataset& geometry, const PlantedScanDraw& draw, bool noise) {
  Dataset out = geometry;
  const int ir = geometry.channel_index("range"), ic = geometry.channel_index("class"),
            iaz = geometry.channel_index("azimuth"), iinc = geometry.channel_index("incidence");
  const auto s = geometry.pgm.shape();
  const std::size_t plane = static_cast<std::size_t>(s.h) * s.w;
  const float* P = geometry.pgm.data();
  const float* M = geometry.mask.data();
  float* T = out.target.data();
  Rng rng(mix(draw.seed ^ 0x6e6f697365ULL));  // the noise stream, apart from the parameters' stream
  for (int n = 0; n < s.n; ++n) {
    auto ch = [&](int k, std::size_t cell) { return P[(static_cast<std::size_t>(n) * s.c + k) * plane + cell]; };
    for (std::size_t cell = 0; cell < plane; ++cell) {
      const std::size_t at = n * plane + cell;
      if (!(M[at] > 0)) {
        T[at] = 0;
        continue;
      }
      const int row = static_cast<int>(cell / s.w), cls = static_cast<int>(ch(ic, cell));
      const double range = ch(ir, cell);
      const double truth = draw.base(cls, range) * draw.effect.gain_at(row, range, ch(iaz, cell), ch(iinc, cell), cls);
      T[at] = static_cast<float>(truth + (noise ? draw.base.sigma * rng.normal() : 0.0));
    }
  }
  return out;
}

PlantedScore score_planted(const PlantedScanDraw& draw, const nlohmann::json& loop, double floor) {
  for (const char* key : {"added_effect", "rmse_before", "rmse_after"})
    if (!loop.contains(key)) throw Error(std::string("planted scans: the loop's JSON has no \"") + key + "\"");
  PlantedScore s;
  if (loop["added_effect"].is_string()) s.added = loop["added_effect"].get<std::string>();
  const double var = draw.base.sigma * draw.base.sigma;
  auto excess = [&](double rmse) { return std::sqrt(std::max(0.0, rmse * rmse - var)); };
  s.excess_before = excess(loop["rmse_before"].get<double>());
  s.excess_after = excess(loop["rmse_after"].get<double>());
  const auto& ok = draw.effect.accepted;
  s.named = !s.added.empty() && std::find(ok.begin(), ok.end(), s.added) != ok.end();
  s.cut = s.excess_after <= kPlantedErrorRatio * s.excess_before;
  s.false_add = !s.added.empty() && !s.named;
  s.hit = draw.effect.scoring == PlantedScoring::Detect ? s.named && s.cut : s.added.empty();
  auto above = [&](double e) { return std::sqrt(std::max(0.0, e * e - floor * floor)); };
  s.floor = floor;
  s.above_floor_before = above(s.excess_before);
  s.above_floor_after = above(s.excess_after);
  s.hit_above_floor = draw.effect.scoring == PlantedScoring::Detect
                          ? s.named && s.above_floor_after <= kPlantedErrorRatio * s.above_floor_before
                          : s.added.empty();
  return s;
}

}  // namespace lidarsim::data
