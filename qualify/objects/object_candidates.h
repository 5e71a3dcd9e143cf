#pragma once
// The object loop's candidate effects (internal to qualify/). For a target (an error of the
// matched detection, or detection itself) and a feature, an effect form is fitted on a fold's fit
// sequences and judged on its held-out sequences by a loss per held-out object:
//   mean_table     per-class binned bias on an error (the loop's first form)     squared error
//   mean_window    one bias inside a window of the feature with fitted edges    squared error
//   mean_line      per-class straight line in the feature (object_terms.h)      squared error
//   mean_relative_line  size targets only: the object's own size (length, width,  squared error
//                  height) x a per-class straight line in the feature, a share of the size
//                  (object_terms.h backfit_relative_line); carried in the KPI model as a term
//                  with relative_to
//   rate_table     per-class binned shift of the detection probability          Bernoulli deviance
//   rate_window    one shift inside a window with fitted edges                  Bernoulli deviance
//   rate_gain      the cell's probability x one gain inside a window with fitted  Bernoulli deviance
//                  edges, the cells refitted with it (object_rate_gain.h)
//   spread_table   the error's sigma x a scale per bin (pooled over classes)     Gaussian deviance
//   spread_window  the error's sigma x one scale inside, one outside a window    Gaussian deviance
//   spread_growth  range only: the error's sigma x (range / its range bin's mean   Gaussian deviance
//                  range)^k, one k: a sigma that grows with range within the model's own range
//                  bins (the model holds a sigma per range bin; equal-count bins of range straddle
//                  its edges and score about 0 on what is left)
//   spread_line    the error's sigma x (1 + b x) on x clamped to its 1-99 %      Gaussian deviance
//                  quantiles, one b, with each (class, range bin)'s level refitted with it
//                  (object_spread_forms.h): a sigma that grows with the feature, held by the
//                  cells where the feature is constant per cell (speed: parked cars and walking
//                  pedestrians need their own levels), within them where it is not (range)
// A window is the best contiguous run of up to 40 equal-count bins of the fit split (a run that
// touches an end is a step), chosen by the between-groups sum of squares (bias forms) or the
// Gaussian likelihood ratio of two variances (spread forms); at least 30 fit samples each side.
// Bias forms are refitted jointly with the model's own cells (backfitting, object_terms.h).
// Bias forms fitted on a fold with Fold::shrink_terms set are shrunk by their own
// track-bootstrap uncertainty (object_terms.h shrink_by_track_bootstrap) before they are judged.
// Spread forms are measured around the fit split's per-class x range-bin mean, in units of that
// cell's standard deviation, so a feature-dependent bias does not pose as a spread.
#include <array>
#include <limits>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "qualify/objects/object_terms.h"

namespace lidarsim::qualify::obj {

enum class Kind { MeanTable, MeanWindow, RateTable, RateWindow, SpreadTable, SpreadWindow, MeanLine, SpreadGrowth,
                  SpreadLine, RateGain, MeanRelativeLine };
// The two line forms of a mean (mean_line, mean_relative_line), compared with the table.
bool is_mean_line(Kind k);
std::string to_string(Kind k);
bool is_spread(Kind k);
bool is_window(Kind k);
std::vector<Kind> kinds_for(int target);  // errors: mean and spread forms; detection: rate forms
// Whether form `kind` applies to feature `feature` (spread_growth: range only).
bool kind_applies(Kind kind, const std::string& feature);
// The spread_growth scale: per range bin `cell` (its fit records' mean x), sigma x (x / mean)^k with
// one k by maximum likelihood of the squared standardised residuals u2 (a sigma the model's bins
// hold on average, growing within each); as a table of 8 equal-width sub-bins per range bin.
BinnedTable fit_scale_growth(const std::vector<double>& x, const std::vector<double>& u2, const std::vector<int>& cell,
                             double* k_out = nullptr);

// Whether the base KPI model (sensor/kpi_model.h) already conditions target t on the feature in
// the form `kind`, so the candidate would only refit what the model has (kObjectModelConditions):
// class conditions everything (a model per class); occlusion (the visibility bin) conditions
// detection (probability per range x visibility bin) and the errors' spread (sigma x
// visibility_std_scale), not an error's mean. Range is held only in the model's fixed bins, and
// candidates are fitted net of them, so no range form is held. Such candidates are judged and
// listed but never ranked or added.
bool used_by_model(const std::string& feature, int target, Kind kind);

struct Effect {
  Kind kind = Kind::MeanTable;
  int target = 0, feature = 0;
  Refit bias;         // bias forms: the term with its cell offsets
  BinnedTable scale;  // spread forms: sigma multiplier per bin of the feature (pooled over classes)
  std::map<std::pair<int, int>, double> cell_mean, cell_sd;  // spread forms: per (class, range bin), fit split
  double class_sd[kObjectClassCount] = {1, 1, 1};
  double growth = 0;  // spread_growth: the exponent k
  // spread_line: per (class, range bin) the refitted level over sd(), keyed as sd() finds it (a
  // cell without its own sd: (class, -1)); empty: 1 everywhere.
  std::map<std::pair<int, int>, double> cell_level;
  double mean(int cls, int cell) const;
  double sd(int cls, int cell) const;
  double level(int cls, int cell) const;  // cell_level's, 1 where absent
};
Effect fit_effect(const Fold& k, int t, int f, Kind kind, int nvis, int bins);

// Per held-out record of target t in fold k: the loss before (base model) and after (with e), and
// what the reported error needs: x (feature), centred residual and predicted sd (spread forms).
struct Losses {
  std::vector<double> before, after;
  std::vector<double> x, centred, sd_before, sd_after;  // spread forms only
};
Losses held_losses(const Fold& k, const Effect& e, int nvis);

// Bernoulli deviance of outcome y under probability p (clamped to [0.005, 0.995]).
double deviance(double y, double p);
// Spread error: held-out objects in `bins` equal-count bins of x; per bin log(measured sd /
// predicted sd) with measured sd = RMS of the centred residual, predicted = RMS of sd; the
// count-weighted RMS over bins. 0 when the spread is right in every bin.
double spread_error(const std::vector<double>& x, const std::vector<double>& centred, const std::vector<double>& sd,
                    int bins = 10);

struct Candidate {
  Kind kind = Kind::MeanTable;
  int target = 0, feature = 0;
  double score = 0;                      // held-out: R^2, deviance R^2 (rate) or 1 - exp(-gain) (spread)
  std::array<double, 2> interval{0, 0};  // its basic block-bootstrap 95% interval over held-out tracks
  double error_before = 0, error_after = 0;  // RMS (mean), deviance per object (rate), spread error (spread)
  double effect_size = 0;  // largest |bias| (mean, rate) or largest / smallest scale (spread), fold 1
  std::string form;        // fold 1's fitted form, e.g. "window [-0.61, -0.26)" or "table, 10 bins"
  long n = 0;              // held-out objects over both folds
  int fold_set = 0;        // the folds it was judged on (object_loop.cpp: 0 sequences, 1 time blocks)
  // Why the held-out data cannot decide on it (empty: it can), in words a user acts on; set when
  // it is judged. Such a candidate may still be added when it passes, but is never "ruled out".
  std::string undecided;
  // Per track block of its fold set (FoldSet::block ids, empty blocks included): the held-out loss
  // sums (after, before, n) its score is a statistic of (score_of_sums).
  BlockSums blocks;
  // The score's lower bound simultaneous over every candidate of its family, whichever the scores
  // pick (object_selection.h; NaN: not computed), its critical value and the family's size.
  double selection_lower = std::numeric_limits<double>::quiet_NaN();
  double selection_critical = 0;
  int selection_family = 0;
  // mean_line and mean_relative_line only: basic block-bootstrap 95 % interval of its score minus the mean_table's of the
  // same feature and target, on the same held-out track blocks (NaN: not compared).
  std::array<double, 2> vs_table{std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::quiet_NaN()};
};
bool used_by_model(const Candidate& c);
// Whether the candidate's selection-aware bound lies above 0 (true when it was not computed).
bool clears_selection(const Candidate& c);
// A line is a second mean form of the same feature beside the table: it is kept only where it beats
// the table on the same held-out tracks (vs_table above 0), so a line is never picked over the
// table on the noise between two near-equal fits. True for every other form, and when not compared.
bool line_over_table(const Candidate& c);
// Sets vs_table of every mean_line and mean_relative_line in cands from the mean_table of its
// feature and target.
void compare_lines_with_tables(std::vector<Candidate>& cands);

// A candidate's score from its held-out loss sums (after, before, n): the R^2 1 - after / before
// (bias forms) or 1 - exp(-(before - after) / n) (spread forms).
double score_of_sums(Kind kind, const std::array<double, 3>& sums);

// Fits and judges one candidate on both folds; block[k][i] = the track block of fold k's i-th
// held-out record of target t.
Candidate judge_candidate(const std::array<Fold, 2>& folds, int t, int f, Kind kind, int nvis, int bins,
                          const std::array<std::vector<int>, 2>& block, size_t nblocks);

// The base model with a spread term: sigma of target t's error x scale per bin of the feature.
sensor::KpiModel with_spread_term(const sensor::KpiModel& base, const Effect& e, const std::string& feature);

// The model `recipe` describes, refitted on the sequences fit_idx only: sensor::fit_kpi_model on
// them plus every conditional term the recipe carries (on an error: a spread table when it has a
// scale, else a mean table; on detection: a rate table), each refitted on the same sequences with
// the loop's forms (object_candidates.h), for the classes that carry it (a mean table with the
// noise shrunk, object_terms.h with_term_and_noise). For held-out checks of a model that carries terms.
// shrink_terms, pool_track_spread: as Fold's. A recipe with false-positive persistence gets it
// refitted on the same sequences (its re-simulation drawn with `seed`).
sensor::KpiModel refit_recipe(const TrackingData& data, const std::vector<int>& fit_idx, const sensor::KpiModel& recipe,
                              int bins = 10, TermShrink shrink_terms = TermShrink::Off,
                              bool pool_track_spread = false, std::uint64_t seed = 1);

}  // namespace lidarsim::qualify::obj
