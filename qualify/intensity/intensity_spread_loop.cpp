// The closed loop on the spread of intensity: out-of-fold residuals of the class x range lookup,
// judged by the range-noise loop's machinery (intensity_spread_loop.h says what and why), and the
// planted spreads its tests and campaign draw.
#include "qualify/intensity/intensity_spread_loop.h"

#include <algorithm>
#include <cmath>
#include <map>

#include "common/error.h"
#include "data/baselines.h"
#include "infer/intensity_model.h"
#include "pgm/materials.h"
#include "qualify/intensity/intensity.h"
#include "qualify/intensity/intensity_internal.h"
#include "qualify/similarity.h"

namespace lidarsim::qualify {

namespace {

constexpr double kSpreadPi = 3.14159265358979323846;
constexpr double kGaussianLogScale = -0.6351814;  // E log|Z| for a standard normal Z
constexpr int kMinFittedCells = 20;  // a mean of n fit cells adds 1/n of the noise's variance: 5 % at 20

int spread_channel(const data::Dataset& ds, const char* name, const std::string& where) {
  try {
    return ds.channel_index(name);
  } catch (const Error& e) {
    throw Error(where + ": " + e.what());
  }
}

double degrees_0_360(double rad) { return std::fmod(rad * 180 / kSpreadPi + 720.0, 360.0); }

// Residuals against a checkpoint's mean, each with the log-scale its spread head predicts.
std::vector<LoopResidual> model_residuals(const data::Dataset& ds, const std::string& checkpoint,
                                          const std::vector<sensor::RangeNoiseTerm>& terms) {
  infer::IntensityModel model = infer::IntensityModel::load(checkpoint);
  model.set_spread_terms(terms);
  const auto head = model.spread();
  if (!head)
    throw Error(checkpoint + ": /config/unet.heads: no spread head (train with --heads mean,log_scale_laplace)");
  // E log|Z| of the head's unit shape: Laplace -Euler's gamma, Gaussian -0.635. A residual table
  // changes the shape, not by feature: the loop's range levels take the difference.
  const double shape = *head == nn::HeadKind::log_scale_laplace ? -0.5772157 : kGaussianLogScale;
  const int ir = ds.channel_index("range"), ic = ds.channel_index("class"), im = ds.channel_index("material"),
            iaz = ds.channel_index("azimuth"), iinc = ds.channel_index("incidence");
  const auto s = ds.pgm.shape();
  const std::size_t plane = static_cast<std::size_t>(s.h) * s.w;
  std::vector<LoopResidual> out;
  std::vector<float> mean, scale;
  for (int n = 0; n < s.n; ++n) {
    model.predict_distribution(ds.frame_pgm(n), mean, scale);
    auto ch = [&](int k, std::size_t cell) { return ds.pgm.data()[(static_cast<std::size_t>(n) * s.c + k) * plane + cell]; };
    for (std::size_t cell = 0; cell < plane; ++cell) {
      if (!(ds.mask.data()[n * plane + cell] > 0) || !(scale[cell] > 0)) continue;
      LoopResidual x;
      x.scan = n;
      x.r.range = ch(ir, cell);
      x.r.residual = ds.target.data()[n * plane + cell] - mean[cell];
      x.r.incidence = ch(iinc, cell);
      x.r.intensity = mean[cell];
      x.r.class_id = static_cast<int>(ch(ic, cell));
      x.r.material = static_cast<int>(ch(im, cell));
      x.r.row = static_cast<int>(cell / s.w);
      x.r.azimuth_deg = static_cast<float>(degrees_0_360(ch(iaz, cell)));
      x.offset = static_cast<float>(std::log(scale[cell]) + shape);
      out.push_back(x);
    }
  }
  return out;
}

}  // namespace

std::vector<LoopResidual> intensity_spread_residuals(const data::Dataset& ds, const IntensitySpreadOptions& o) {
  const std::string where = "loop intensity-spread";
  for (const char* c : {"range", "class", "material", "azimuth", "incidence"}) spread_channel(ds, c, where);
  if (o.model.empty() && !o.spread_terms.empty())
    throw Error(where + ": spread terms apply to a model's spread head: give the model too");
  if (!o.model.empty()) {
    auto out = model_residuals(ds, o.model, o.spread_terms);
    if (out.empty()) throw Error(where + ": the scans have no returns");
    return out;
  }
  const data::SectorSplit split = intensity_split(ds, o.split);
  const auto folds = intensity_detail::make_folds(ds, split, o.folds);
  const auto at = [](const char* name) {
    return static_cast<std::size_t>(std::find(kIntensityFeatures.begin(), kIntensityFeatures.end(), name) -
                                    kIntensityFeatures.begin());
  };
  const std::size_t fr = at("range"), finc = at("incidence_angle"), faz = at("azimuth"), fmat = at("material");
  std::vector<LoopResidual> out;
  for (const auto& f : folds) {
    const IntensityCells& c = f.cells;
    const std::vector<double> mean = lookup_prediction(c);  // fitted on this fold's fit cells only
    // A cell whose class x range key the fold's fit cells hardly hold gets a fallback mean (the
    // class's, or the global one): its residual is the mean's error, not the spread around a mean
    // the model has, so it is left out.
    std::map<long, int> fitted_cells;
    auto key = [&](std::size_t i) { return static_cast<long>(c.cls[i]) * 1000 + data::range_bin(c.feature[fr][i]); };
    for (std::size_t i = 0; i < c.size(); ++i)
      if (!c.held_out[i]) ++fitted_cells[key(i)];
    for (std::size_t i : f.held) {
      if (const auto it = fitted_cells.find(key(i)); it == fitted_cells.end() || it->second < kMinFittedCells) continue;
      LoopResidual x;
      x.scan = c.frame[i];
      x.r.range = static_cast<float>(c.feature[fr][i]);
      x.r.residual = static_cast<float>(c.measured[i] - mean[i]);
      x.r.incidence = static_cast<float>(c.feature[finc][i]);
      x.r.intensity = static_cast<float>(mean[i]);  // the predicted mean, never the measured value
      x.r.class_id = c.cls[i];
      x.r.material = static_cast<int>(c.feature[fmat][i]);
      x.r.row = c.row[i];
      x.r.azimuth_deg = static_cast<float>(degrees_0_360(c.feature[faz][i]));
      out.push_back(x);
    }
  }
  if (out.empty()) throw Error(where + ": the scans have no returns");
  return out;
}

RangeLoopResult loop_intensity_spread(const data::Dataset& ds, const IntensitySpreadOptions& o) {
  const std::vector<LoopResidual> residuals = intensity_spread_residuals(ds, o);
  RangeLoopOptions lo = o.loop;
  lo.fit_range_model = false;  // the written range-noise model has no meaning for intensity
  return loop_range_noise(residuals, residuals, lo);
}

nlohmann::json intensity_spread_json(const RangeLoopResult& r, bool model) {
  nlohmann::json j = to_json(r);
  j["metric"] = model ? "held-out mean (log|e| - the spread head's log-scale - the loop's base)^2 per return, e = measured "
                        "intensity - the checkpoint's mean; folds = rotated azimuth sectors with guard bands"
                      : "held-out mean (log|e| - predicted log-scale)^2 per return, e = measured intensity - the class x "
                        "range lookup's mean fitted out of fold; folds = rotated azimuth sectors with guard bands";
  for (auto* list : {&j["candidates"], j.contains("added") ? &j["added"] : nullptr}) {
    if (!list) continue;
    auto fix = [](nlohmann::json& c) {
      auto& f = c["fitted"];
      if (f.contains("extra_sigma_mm_per_m")) {
        f["extra_sigma_per_m"] = f["extra_sigma_mm_per_m"].get<double>() / 1000;
        f.erase("extra_sigma_mm_per_m");
      }
    };
    if (list->is_array())
      for (auto& c : *list) fix(c);
    else
      fix(*list);
  }
  return j;
}

// ---- planted spread ----

const std::vector<PlantedSpreadFamily>& all_planted_spread_families() {
  static const std::vector<PlantedSpreadFamily> f = {PlantedSpreadFamily::LaserBlock, PlantedSpreadFamily::AzimuthWindow,
                                                     PlantedSpreadFamily::OneClass, PlantedSpreadFamily::Incidence,
                                                     PlantedSpreadFamily::Control};
  return f;
}

std::string to_string(PlantedSpreadFamily f) {
  switch (f) {
    case PlantedSpreadFamily::LaserBlock: return "laser_block";
    case PlantedSpreadFamily::AzimuthWindow: return "azimuth_window";
    case PlantedSpreadFamily::OneClass: return "one_class";
    case PlantedSpreadFamily::Incidence: return "incidence";
    case PlantedSpreadFamily::Control: return "control";
  }
  return "?";
}

PlantedSpreadFamily planted_spread_family_from_string(const std::string& name) {
  for (PlantedSpreadFamily f : all_planted_spread_families())
    if (to_string(f) == name) return f;
  throw Error("unknown planted spread family \"" + name + "\" (laser_block, azimuth_window, one_class, incidence, control)");
}

double PlantedSpread::sigma_at(double sigma, int row, double azimuth_deg, double incidence_rad, int cls) const {
  switch (family) {
    case PlantedSpreadFamily::LaserBlock: return row >= row_first && row <= row_last ? sigma * factor : sigma;
    case PlantedSpreadFamily::AzimuthWindow:
      return std::fmod(azimuth_deg - azimuth_start_deg + 720.0, 360.0) < azimuth_width_deg ? sigma * factor : sigma;
    case PlantedSpreadFamily::OneClass: return cls == class_id ? sigma * factor : sigma;
    case PlantedSpreadFamily::Incidence: {
      const double deg = std::isfinite(incidence_rad) ? std::clamp(incidence_rad * 180 / kSpreadPi, 0.0, 90.0) : 0.0;
      return sigma * (1 + per_90deg * deg / 90);
    }
    case PlantedSpreadFamily::Control: return sigma;
  }
  return sigma;
}

PlantedSpread draw_planted_spread(PlantedSpreadFamily family, std::uint64_t seed, const data::Dataset& geometry,
                                  double sigma) {
  if (!(sigma > 0)) throw Error("planted spread: sigma: expected > 0, got " + std::to_string(sigma));
  SplitMix rng(seed * 0x9E3779B97F4A7C15ULL + 0x7370726561ULL);
  auto uniform = [&](double a, double b) { return a + (b - a) * rng.uniform(); };
  PlantedSpread e;
  e.family = family;
  e.factor = uniform(1.6, 3.0);
  e.parameters = {{"family", to_string(family)}, {"seed", seed}, {"sigma", sigma}};
  const int H = geometry.rows();
  switch (family) {
    case PlantedSpreadFamily::LaserBlock: {
      const int len = std::max(1, static_cast<int>(std::lround(uniform(0.10, 0.25) * H)));
      e.row_first = static_cast<int>(rng.uniform() * (H - len + 1));
      e.row_last = e.row_first + len - 1;
      e.accepted = {"laser"};
      e.parameters.update({{"rows", {e.row_first, e.row_last}}, {"factor", e.factor}});
      break;
    }
    case PlantedSpreadFamily::AzimuthWindow:
      e.azimuth_start_deg = uniform(0, 360), e.azimuth_width_deg = uniform(30, 120);
      e.accepted = {"azimuth"};
      e.parameters.update({{"start_deg", e.azimuth_start_deg}, {"width_deg", e.azimuth_width_deg}, {"factor", e.factor}});
      break;
    case PlantedSpreadFamily::OneClass: {
      // The classes holding >= 5 % of the returns.
      const int ic = geometry.channel_index("class");
      std::vector<long> count(pgm::cls::count, 0);
      long total = 0;
      const auto s = geometry.pgm.shape();
      const std::size_t plane = static_cast<std::size_t>(s.h) * s.w;
      for (int n = 0; n < s.n; ++n)
        for (std::size_t cell = 0; cell < plane; ++cell)
          if (geometry.mask.data()[n * plane + cell] > 0) {
            const int k = static_cast<int>(geometry.pgm.data()[(static_cast<std::size_t>(n) * s.c + ic) * plane + cell]);
            if (k >= 0 && k < pgm::cls::count) ++count[k], ++total;
          }
      std::vector<int> eligible;
      for (int k = 0; k < pgm::cls::count; ++k)
        if (total > 0 && count[k] >= 0.05 * total) eligible.push_back(k);
      if (eligible.empty()) throw Error("planted spread: no class holds 5 % of the returns");
      e.class_id = eligible[std::min(eligible.size() - 1, static_cast<std::size_t>(rng.uniform() * eligible.size()))];
      e.accepted = {"class"};
      e.parameters.update({{"class", e.class_id}, {"factor", e.factor}});
      break;
    }
    case PlantedSpreadFamily::Incidence:
      e.per_90deg = uniform(1.0, 2.5), e.factor = 1;
      e.accepted = {"incidence"};
      e.parameters.update({{"per_90deg", e.per_90deg}});
      break;
    case PlantedSpreadFamily::Control: e.factor = 1; break;
  }
  return e;
}

data::Dataset plant_spread(const data::Dataset& geometry, const data::PlantedScanDraw& base, const PlantedSpread& e,
                           std::uint64_t seed) {
  const std::string where = "planted spread";
  const int ir = spread_channel(geometry, "range", where), ic = spread_channel(geometry, "class", where),
            iaz = spread_channel(geometry, "azimuth", where), iinc = spread_channel(geometry, "incidence", where);
  data::Dataset out = geometry;
  const auto s = geometry.pgm.shape();
  const std::size_t plane = static_cast<std::size_t>(s.h) * s.w;
  const float* P = geometry.pgm.data();
  const float* M = geometry.mask.data();
  float* T = out.target.data();
  SplitMix rng(seed ^ 0x6e6f6973655350ULL);
  for (int n = 0; n < s.n; ++n) {
    auto ch = [&](int k, std::size_t cell) { return P[(static_cast<std::size_t>(n) * s.c + k) * plane + cell]; };
    for (std::size_t cell = 0; cell < plane; ++cell) {
      const std::size_t at = n * plane + cell;
      if (!(M[at] > 0)) {
        T[at] = 0;
        continue;
      }
      const int row = static_cast<int>(cell / s.w), cls = static_cast<int>(ch(ic, cell));
      const double sd = e.sigma_at(base.base.sigma, row, degrees_0_360(ch(iaz, cell)), ch(iinc, cell), cls);
      T[at] = static_cast<float>(base.base(cls, ch(ir, cell)) + sd * rng.normal());
    }
  }
  return out;
}

SpreadTruth spread_truth(const std::vector<LoopResidual>& residuals, const RangeLoopResult& r, const PlantedSpread& e,
                         double sigma) {
  SpreadTruth t;
  double b = 0, a = 0;
  for (std::size_t i = 0; i < residuals.size() && i < r.b_before.size(); ++i) {
    if (!std::isfinite(r.b_before[i]) || !std::isfinite(r.b_after[i])) continue;
    const auto& x = residuals[i].r;
    const double truth = std::log(e.sigma_at(sigma, x.row, x.azimuth_deg, x.incidence, x.class_id)) + kGaussianLogScale;
    b += std::pow(r.b_before[i] - truth, 2), a += std::pow(r.b_after[i] - truth, 2), ++t.n;
  }
  if (t.n > 0) t.before = std::sqrt(b / t.n), t.after = std::sqrt(a / t.n);
  return t;
}

}  // namespace lidarsim::qualify
