#pragma once
// The closed loop on range noise (docs/range-noise.md, "The loop on range noise"): residuals of
// local surface fits (range_noise_fit.h) on measured scans, their log-scale against every feature
// a residual offers, candidates judged held out on rotated azimuth folds with guard bands.
//
//   metric     y = log|e| of each residual e (along the beam, m). A spread model predicts the
//              log-scale b = E[log|e|]; for a Gaussian of spread s, b = log s - 0.635. The error
//              is the mean of (y - b)^2: pi^2 / 8 = 1.234 for a Gaussian whose spread is right,
//              plus (log m)^2 when it is off by a factor m; tails weigh little on a log scale.
//   base       the range-noise model's form: a log-scale per 5 m range bin (the fitted spread per
//              range bin), plus the terms the model already carries (`base_terms`: a log-scale
//              shift per bin of each feature, fitted with it by backfitting), fitted on the
//              reference residuals of the fit sectors only.
//   folds      `sectors` azimuth sectors (rotated by `rotation_deg`), sector s in fold s mod
//              `folds`, so every azimuth is held out once and every 10 deg bin is seen by every
//              fold's fit. Guard bands: a residual within `guard_deg` of a boundary with another
//              fold's sector is neither fitted nor scored in that fold (its neighbourhood reads
//              ranges on the far side), so no fitted residual shares a point with a scored one.
//   candidates per feature (laser, range, class, material, azimuth, incidence, intensity) a
//              table of log-scale shifts per bin (a spread factor exp(shift)), shrunk towards 0
//              with `shrink` pseudo residuals, and for ordered features a window (one shift over
//              a contiguous run of bins, circular for azimuth); for range also "growth", a spread
//              c r added in quadrature (the model's own smooth form, one parameter).
//   judged     score = 1 - E(candidate) / E(base) over every fold's scored residuals; interval and
//              the selection-aware bound from the max-T block bootstrap (blocks = one scan's
//              sector) shared with the return loop (qualify/returns/max_t.h). The best candidate
//              is added when its bound is above 0 and its score at least `min_gain`.
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "qualify/range_noise/range_noise_fit.h"
#include "qualify/returns/term_form.h"
#include "sensor/range_noise.h"

namespace lidarsim::qualify {

struct LoopResidual {
  int scan = 0;  // unique over the loop's input
  RangeResidual r;
  // A model's own predicted log-scale E log|e| for this residual (0: none). The loop then models
  // log|e| - offset: its base and terms are what the model's spread lacks (the intensity-spread
  // loop on a checkpoint's spread head). The growth form assumes offset 0.
  float offset = 0;
};

// The loop's input from labelled scans: residuals of every planar class (default fit options).
std::vector<LoopResidual> loop_residuals(const std::vector<pgm::Point>& points, const pgm::BeamLayout& layout, int scan,
                                         const std::string& source);

struct RangeLoopOptions {
  int folds = 4;
  int sectors = 64;              // 5.6 deg each
  double rotation_deg = 0;       // the sector grid's origin
  double guard_deg = 0.5;        // > the K = 1 neighbourhood (2 x 0.17 deg on the HDL-64E)
  double shrink = 50;            // pseudo residuals of a bin's shift towards 0
  double min_gain = 0.002;
  double level = 0.95;
  int replicates = 400;
  std::uint64_t seed = 23;
  // Features the base carries as tables (the model's terms); "range growth" = the growth form.
  std::vector<std::string> base_terms;
  // Fit RangeLoopResult::model (false: the residuals are not ranges, e.g. the intensity-spread loop).
  bool fit_range_model = true;
};

struct RangeCandidate {
  std::string feature;
  TermForm form = TermForm::table;  // table | window | growth
  double score = 0, se = 0, lower = 0, upper = 0, selection_lower = 0;
  std::string decision, reason;
  sensor::RangeNoiseTerm term;  // fitted on every target residual against the base on every reference one
  double extra_per_m = 0;       // the growth form's c (m per m)
  nlohmann::json fitted;
};

struct RangeLoopResult {
  int scans = 0, folds = 0;
  long long residuals = 0, scored = 0;
  double error_before = 0, error_after = 0;  // held-out mean (y - b)^2 over the scored residuals
  double critical = 0;
  std::vector<RangeCandidate> candidates;    // ranked by score
  int added = -1;
  std::string added_feature;
  // Per target residual: its fold and whether it is scored; the held-out log-scale before and
  // after (NaN where not scored).
  std::vector<int> fold;
  std::vector<float> b_before, b_after;
  sensor::RangeNoiseModel model;  // the range table refitted with the base terms and the added one (fit_range_model)
  // The base terms refitted on every residual and the added one (the model's terms), and the base's
  // range level exp(log-scale per range bin less its mean over the residuals): with offsets, the
  // factor by which the model's spread by range is off.
  std::vector<sensor::RangeNoiseTerm> terms;
  sensor::RangeNoiseTerm range_level;
};

// The loop; `reference` = the residuals the base is fitted on (the target itself for a loop on
// one place; the campaign's are the scans before the plant). Throws when either is empty.
RangeLoopResult loop_range_noise(const std::vector<LoopResidual>& target, const std::vector<LoopResidual>& reference,
                                 const RangeLoopOptions& options = {});

// The name under which an added candidate enters the next round's base_terms.
std::string base_term_name(const RangeCandidate& c);

// Held-out error (mean (y - b)^2, y = log|e| - offset) over the residuals where b is finite.
double log_scale_error(const std::vector<LoopResidual>& target, const std::vector<float>& b);

nlohmann::json to_json(const RangeLoopResult& r);
// subject: what the residuals are, in the title ("range noise", "intensity spread").
std::string to_markdown(const RangeLoopResult& r, const std::string& command, const std::string& subject = "range noise");

// `lidar-qualify loop range-noise --semantickitti DIR --report R.json [--out-model M.json] [--rounds N]`.
int run_loop_range_noise(int argc, char** argv);

// ---- planted range noise (the campaign and the tests) ----
// Extra Gaussian noise along each beam, on top of the measured scan's own: extra spread
// s(point) drawn with sensor::range_noise_normal(seed, scan, point index).
// Enumerators keep their values (the campaign's seeds derive from them): new ones go last.
enum class PlantedRangeFamily { RangeGrowth, LaserNoise, ClassNoise, Control, AzimuthNoise, IncidenceNoise, IntensityNoise };
const std::vector<PlantedRangeFamily>& all_planted_range_families();
std::string to_string(PlantedRangeFamily f);
PlantedRangeFamily planted_range_family_from_string(const std::string& name);

// What a planted effect may depend on, for one point.
struct PlantedPoint {
  int row = 0;
  double range_m = 0;
  int class_id = 0;
  double azimuth_deg = 0;      // atan2(y, x) in [0, 360), the residuals' convention
  double incidence_rad = NAN;  // NaN when not estimated
  double intensity = 0;
};

struct PlantedRangeEffect {
  PlantedRangeFamily family = PlantedRangeFamily::Control;
  std::vector<std::string> accepted;  // loop feature names that count as naming it (empty: control)
  double per_metre = 0;               // RangeGrowth: s = per_metre x range
  std::vector<double> row_sigma;      // LaserNoise: s per row (0 elsewhere)
  int class_id = -1;                  // ClassNoise
  double sigma = 0;                   // ClassNoise, AzimuthNoise, IntensityNoise: s where it acts
  double window_start_deg = 0, window_width_deg = 0;  // AzimuthNoise: [start, start + width), circular
  double per_tan = 0;                 // IncidenceNoise: s = per_tan x tan(min(incidence, 80 deg))
  double intensity_below = 0;         // IntensityNoise: acts on returns weaker than this
  nlohmann::json parameters;
  double extra_sigma(const PlantedPoint& p) const;  // m
};

// Draws one effect of `family` from `seed`: RangeGrowth s = a r with a in 0.5-2 mm/m; LaserNoise
// 2-10 lasers (among those holding >= 0.5 % of the residuals: `row_share`), each 1-3 cm;
// ClassNoise one planar class holding >= 5 % of the residuals (`class_share`) at 1-3 cm;
// AzimuthNoise 1-3 cm over a window 20-120 deg wide anywhere in 0-360 deg (a sector the sensor
// sees through a dirty or damaged window); IncidenceNoise s = a tan(incidence), a in 2-5 mm (the
// footprint stretched at grazing angles; 80 deg caps it); IntensityNoise 1-3 cm on the returns
// below a quantile 0.1-0.4 of the residuals' intensities (`intensity_quantiles`, 0..100 %).
PlantedRangeEffect draw_planted_range(PlantedRangeFamily family, std::uint64_t seed, const std::vector<double>& row_share,
                                      const std::vector<double>& class_share,
                                      const std::vector<double>& intensity_quantiles);

// The scan with the effect planted (each point moved along its beam); rows from the projection
// onto `layout` (the same rows range_noise_fit reads).
std::vector<pgm::Point> plant_range_noise(const std::vector<pgm::Point>& points, const pgm::BeamLayout& layout,
                                          const PlantedRangeEffect& effect, std::uint64_t seed, std::uint64_t scan);

// ---- one draw of the campaign (bench/loop_campaign_range_noise.cpp and its smoke test) ----
// The measured scans before any plant: their residuals are the reference, and the base terms are
// the loop's best candidate on them, round after round while it cuts the held-out error by at
// least min_gain (the model that was right before the sensor changed, with every effect the
// unplanted scans hold, decided or not), so on a control the base is the truth up to its
// estimation error.
struct RangeCampaignData {
  pgm::BeamLayout layout;
  std::vector<std::vector<pgm::Point>> scans;
  std::vector<LoopResidual> reference;
  std::vector<double> row_share, class_share;  // shares of the residuals per laser and class
  std::vector<double> intensity_quantiles;     // of the residuals' intensities, at 0, 1, ..., 100 %
  std::vector<std::string> base_terms;
};
RangeCampaignData prepare_range_campaign(std::vector<std::vector<pgm::Point>> scans, const pgm::BeamLayout& layout,
                                         const RangeLoopOptions& options, int max_rounds = 6);

// Excess = held-out error minus the oracle's (the loop's own held-out base widened by the planted
// spread, exp(b_o + 0.635)^2 = exp(b + 0.635)^2 + s^2, a Gaussian's log-scale): the base's
// estimation error is in both and cancels. Recall: the planted feature added and the excess after
// <= 0.7 x before; a false add: anything added on a control, or another feature on a plant.
struct RangeDrawResult {
  PlantedRangeEffect effect;
  RangeLoopResult loop;
  double error_oracle = 0, excess_before = 0, excess_after = 0;
  bool named = false, cut = false, hit = false, false_add = false;
};
RangeDrawResult run_range_draw(const RangeCampaignData& data, PlantedRangeFamily family, std::uint64_t seed,
                               RangeLoopOptions options);

}  // namespace lidarsim::qualify
