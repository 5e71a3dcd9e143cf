#pragma once
// Internals of the intensity loop (qualify/intensity/intensity.h), shared by its files:
//   intensity_qualify.cpp     cells, lookups and `lidar-qualify intensity`
//   intensity_folds.cpp       the rotated folds, the base model per fold, the pooled held-out cells
//   intensity_forms.cpp       candidate forms (additive, gain, affine; tables and windows), cross-fitted
//   intensity_loop.cpp        one round as named steps (rank, judge, refit, report) and the rounds
//   intensity_report.cpp      the JSON written from the typed round result
#include <array>
#include <map>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "qualify/intensity/intensity.h"
#include "qualify/residual.h"
#include "train/trainer.h"

namespace lidarsim::qualify::intensity_detail {

struct Errors {
  double mae = 0, rmse = 0;
  long n = 0;
};
Errors errors(const std::vector<double>& pred, const std::vector<double>& meas, const std::vector<size_t>& idx);
Errors errors(const std::vector<double>& pred, const std::vector<double>& meas);  // every cell

std::vector<size_t> held_indices(const IntensityCells& c, int cls = -1);

std::vector<double> pick(const std::vector<double>& v, const std::vector<size_t>& idx);

// Lookup on key(i) fitted on the fit cells; unseen keys fall back to `fallback`.
template <class Key>
std::vector<double> lookup(const IntensityCells& c, Key key, const std::vector<double>& fallback) {
  std::map<long, std::pair<double, long>> t;
  for (size_t i = 0; i < c.size(); ++i)
    if (!c.held_out[i]) {
      auto& e = t[key(i)];
      e.first += c.measured[i];
      ++e.second;
    }
  std::vector<double> out(c.size());
  for (size_t i = 0; i < c.size(); ++i) {
    const auto it = t.find(key(i));
    out[i] = it != t.end() ? it->second.first / it->second.second : fallback[i];
  }
  return out;
}

using Base = IntensityBase;

// The PGM channels that carry a feature into the UNet (azimuth: its sine and cosine).
std::vector<std::string> channels_of(const std::string& feature);
// A copy of the dataset with the derived channels among `names` appended.
data::Dataset with_derived_channels(const data::Dataset& ds, const std::vector<std::string>& names);

// UNets trained on the fit cells of `ds` (its guarded split) with `channels` as input, one per
// seed: per-cell predictions of each seed and their mean.
struct UnetFits {
  std::vector<double> ensemble;
  std::vector<std::vector<double>> seed_pred;
  train::TrainResult first;  // the first seed's model and its checkpoint metadata
};
struct TrainingCount {
  int done = 0, total = 0;
};
UnetFits fit_unets(const data::Dataset& ds, const IntensityCells& c, const std::vector<std::string>& channels,
                   const IntensityLoopOptions& o, const std::string& label, TrainingCount& count,
                   bool row_affine = false);

// One fold of the rotated guarded split. The dataset is rolled by `shift` columns (rolled column
// c = original column (c + shift) mod W), so the guarded split of the rolled scans validates the
// fold's regions with the same guard bands; every model of the fold trains on the rolled scans.
struct Fold {
  int shift = 0;
  data::Dataset ds;
  IntensityCells cells;
  std::vector<size_t> held;  // indices into cells
};

// Cross-fit groups of the candidate forms. Plain (crossed = false): a group's cells are scored by a
// form fitted on every other group. Crossed: group = 2 * class + row block, and a group is scored
// by a form fitted on the cells that share neither its class nor its row block.
struct CrossFit {
  std::vector<int> group;  // per pooled cell
  int groups = 0;          // 0: not in use
  bool crossed = false;
  std::string by;
  bool fits(int apply, int cell) const {
    return crossed ? (apply / 2 != cell / 2 && apply % 2 != cell % 2) : apply != cell;
  }
};

// Every held-out cell of every fold, in fold order: with the regions rotated over 4 folds every
// column is validated once, so these are all the cells with a return, each predicted by a base
// model that did not see its scenery.
struct Pooled {
  std::vector<double> measured, base, lookup;
  std::vector<std::vector<double>> feature;  // [kIntensityFeatures][cell]
  std::vector<int> fold, frame, row, cls;
  std::vector<long> block;  // bootstrap block: 16-column strip of the original columns (all scans) or a frame
  std::vector<int> group;   // cross-fit group of the candidate forms
  std::vector<std::size_t> offset;  // first pooled cell of each fold (folds.size() + 1 entries)
  std::string group_by;             // "scan", "time block (...)", "fold" or "validation region"
  int groups = 1;
  double scenery_correlation = 0;   // scenery_correlation() of the scans
  double time_block_correlation = 0;  // TimeBlocks::cross_correlation
  // When the groups are columns (scans of one scenery): azimuth forms are cross-fitted over
  // classes x row blocks in the same columns instead (scenery_cross_fit), or, where that cannot
  // decide either, azimuth_undecided says why ("" when azimuth can be judged).
  CrossFit azimuth_scenery;
  std::string azimuth_undecided;
  std::string azimuth_columns;  // why the column groups cannot judge azimuth ("" when they can)
  std::size_t size() const { return measured.size(); }
};

// The folds of `ds`: 1 = the guarded split as it is; 4 = its regions rotated by W/8 per fold, so
// that every column is validated once (only for a guarded region split). Throws naming --folds.
std::vector<Fold> make_folds(const data::Dataset& ds, const data::SectorSplit& split, int folds);
// Correlation between scans a and b of the range's deviation from its row mean, cell by cell: how
// much the two show the same scenery at the same cells.
double scan_pair_correlation(const data::Dataset& ds, int a, int b);
// Its mean over consecutive scans.
double scenery_correlation(const data::Dataset& ds);
// From this correlation on the scans are taken for one place (SemanticKITTI's consecutive scans:
// about 0.9; the reference sensor's independent scenes: about 0).
inline constexpr double kSameSceneryCorrelation = 0.5;
// Up to `blocks` blocks of consecutive scans, and the mean scan_pair_correlation over pairs of
// scans in different blocks: what a form fitted on the other blocks shares of a block's scenery.
struct TimeBlocks {
  std::vector<int> block_of_frame;
  int blocks = 1;
  double cross_correlation = 0;
};
TimeBlocks time_blocks(const data::Dataset& ds, int blocks = 4);
// Blocks are cross-fit groups below this mean correlation. Lower than kSameSceneryCorrelation
// (which bounds the correlation of neighbours) because it is a mean over pairs of scans, most of
// them far apart: the blocks' neighbouring scans across a boundary share more than it says.
inline constexpr double kSameSceneryCorrelationBetweenBlocks = 0.2;
// The pooled held-out cells with the lookup's prediction; `base` is left for the caller.
Pooled pool(const std::vector<Fold>& folds, int columns, double scenery, const TimeBlocks& time);
// The azimuth cross-fit for scans of one scenery (intensity_scenery.cpp). A sensor-fixed effect at
// an azimuth scales every material seen there; scenery that mimics it (a dark wall) is one class
// at some rows. So an azimuth form is fitted on the other classes in the other block of rows and
// scored on one class in one block, in the SAME columns (the pooled held-out cells keep the folds'
// guard bands). Sets p.azimuth_scenery, or p.azimuth_undecided with the reason (one class or row
// block, or too few cells of the other classes in the other rows at the cells' azimuths).
// `columns_reason` is what the column groups cannot decide (prefixed to a failure's reason).
void scenery_cross_fit(Pooled& p, const std::string& columns_reason);
// The groups the forms of `feature` are cross-fitted over: azimuth_scenery for azimuth when in use.
CrossFit cross_fit_for(const Pooled& p, const std::string& feature);
inline constexpr int kSceneryFineBins = 32;        // azimuth bins of the coverage check (the windows' fine bins)
inline constexpr long kSceneryMinCellsPerBin = 20;  // fit cells (other classes, other rows) a bin needs to count covered
inline constexpr double kSceneryMinCoverage = 0.5;  // share of cells in covered bins, else undecided

// Per-fold predictions (indexed by each fold's cells) to pooled held-out cells.
std::vector<double> pool_prediction(const std::vector<Fold>& folds, const std::vector<std::vector<double>>& per_fold);

// Block bootstrap 95% interval of the held-out MAE change after - before, over the pooled blocks.
std::array<double, 2> change_interval(const Pooled& p, const std::vector<double>& after);

// --- Candidate forms (intensity_forms.cpp) ---------------------------------------------------------
// RangeSlope: per bin, a gain that is a power of range, measured ~ base * exp(a + s (ln range - c)):
// a range fall-off that differs between lasers (receiver optics focused per laser block). The base
// keys range, so a fall-off common to every cell is in it already; what it cannot carry is the
// interaction of a laser with range, which a per-beam level (table, gain, affine) does not carry
// either. Tried on the features that index lasers only (range_interaction_applies).
enum class Form { Table, Window, GainTable, WindowGain, AffineTable, RangeSlope };
inline constexpr std::array<Form, 6> kForms = {Form::Table,      Form::Window,      Form::GainTable,
                                               Form::WindowGain, Form::AffineTable, Form::RangeSlope};
// "binned table" / "per-beam table", "window", "binned gain" / "per-beam gain", "window gain",
// "binned affine" / "per-row affine", "binned range slope" / "per-beam range slope".
std::string form_name(Form f, bool per_row);
bool additive(Form f);
// Features fixed to a laser, whose interaction with range (Form::RangeSlope) is a sensor effect:
// beam_row and elevation. Elsewhere (height, incidence, class) a per-bin range slope would be a
// second look at the range fall-off the base keys already, and one more chance to fit noise.
bool range_interaction_applies(const std::string& feature);

// A correction fitted on some cells and applied to others: delta(x, base, range) added to the prediction.
struct FittedForm {
  BinnedTable table;          // additive levels, gains, affine offsets, or log gains (RangeSlope)
  std::vector<double> slope;  // per bin: affine on (base - centre); RangeSlope on (ln range - centre)
  double centre = 0;
  Form form = Form::Table;
  bool ok() const { return !table.value.empty(); }
  double delta(double x, double base, double range_m) const { return delta_in(table.bin(x), base, range_m); }
  double delta_in(int bin, double base, double range_m) const;  // delta with x's bin of `table` given
};

// Fits `form` of the winsorised residual rc (= clamp(measured - base)) over x on the cells idx:
// `edges` bin the tables (one bin per beam row for beam_row), `fine` the windows' search; `range`
// (metres) is read by RangeSlope only.
FittedForm fit_form(Form form, const std::vector<double>& edges, const std::vector<double>& fine,
                    const std::vector<double>& x, const std::vector<double>& rc, const std::vector<double>& base,
                    const std::vector<double>& range, const std::vector<size_t>& idx);

// The lookup base (class x 5 m range bin) refitted jointly with a RangeSlope of `feature` (binned
// by `edges`) on the fit cells of `c`: intensity ~ level(class, range bin) x exp(a + s ln range)
// per bin of the feature. A per-laser fall-off biases the plain lookup's levels (each range bin
// averages the changed and unchanged lasers by their share of its cells), so a slope fitted on its
// residual would carry that bias; fitted together, neither does. Per-cell predictions.
std::vector<double> lookup_with_range_slope(const IntensityCells& c, size_t feature, const std::vector<double>& edges);

// A form scored on the pooled held-out residual, cross-fitted over the pool's groups (fitted on the
// other groups, applied to each group in turn).
struct FormScore {
  double r2 = 0;  // held-out share of the residual variance the form explains beyond its one-bin version
  std::array<double, 2> interval{0, 0};
  double mae_after = 0;               // held-out MAE of base + correction
  double effect = 0;                  // RMS of the correction (intensity units); windows: inside - outside
  std::vector<double> corrected;      // base + correction per pooled cell (when asked for)
  FittedForm shown;                   // fitted on every pooled cell: for the report and the plot
};
// `folds` (a lookup base's first round): azimuth gain forms cross-fitted over classes x row blocks
// are scored by lookup_with_azimuth_gain; without it, as every form. `cross`: these groups instead
// of cross_fit_for(p, feature) (a scenery feature judged by the azimuth's crossed split).
FormScore score_form(Form form, const Pooled& p, size_t feature, const std::vector<double>& edges,
                     const std::vector<double>& fine, const std::vector<double>& rc, bool keep_corrected = false,
                     const std::vector<Fold>* folds = nullptr, const CrossFit* cross = nullptr);

// Features whose value at a cell is fixed by the scenery in its columns, as azimuth's is: on scans
// of one scenery (azimuth cross-fitted over classes x row blocks) their column cross-fit carries
// whatever lies in those columns (a window of azimuth over a hill shows up in the hill's heights),
// so they are scored by the crossed split too, and rank by the lower of the two scores.
bool scenery_feature(const std::string& feature);

// An azimuth gain form (GainTable or WindowGain) cross-fitted over classes x row blocks, with each
// fold's lookup refitted jointly: level(class, range bin) = sum m G / sum G^2 over the fold's fit
// cells, G the gain of the cell's azimuth. The plain lookup's levels average the window's gain
// over the share of each class's fit cells inside it, a bias per class that no gain common to
// the classes undoes, and that differs between classes, so a gain fitted on some classes over
// the plain lookup is wrong for the others. The gain of a group (a class in a row block) is fitted
// on the other classes in the other rows over levels refitted with that same gain (kJointRounds
// alternations), so nothing of the group's own cells enters its prediction. Pooled predictions:
// G x level.
std::vector<double> lookup_with_azimuth_gain(const std::vector<Fold>& folds, const Pooled& p, Form form,
                                             const std::vector<double>& edges, const std::vector<double>& fine);
inline constexpr int kJointRounds = 3;
// The azimuth window gain's window, searched as the joint model itself: level(fold, class x range
// bin) x (g_in inside, g_out outside), every window of kWindowFineBins equal-count azimuth bins
// (coarse on every kWindowCoarse-th edge, then each edge refined within one coarse step), the
// levels refitted on the folds' fit cells, the gains and the error on `fit` (pooled held-out cells
// of the other classes in the other rows). A WindowGain form (outside 1, inside g_in / g_out), or empty when no
// window has kWindowMinShare of the cells on each side. intensity_scenery.cpp says why.
FittedForm joint_window_gain(const std::vector<Fold>& folds, const Pooled& p, const std::vector<size_t>& fit,
                             const std::vector<double>& fine);
inline constexpr int kWindowFineBins = 256;
inline constexpr int kWindowCoarse = 4;
inline constexpr double kWindowMinShare = 0.01;
// Whether `form` of `feature` is scored and refitted so (a lookup base's first round only).
bool joint_azimuth_gain(const Pooled& p, const std::string& feature, Form form);

// --- One round's typed result (intensity_loop.cpp fills it, intensity_report.cpp writes it) -------
enum class Decision { Added, NotAdded, Tried, NotTried, NotRanked, CannotDecide };
const char* decision_name(Decision d);  // "added", "not added", ...

struct Candidate {
  std::string feature;
  Form form = Form::Table;
  bool per_row = false;
  bool used = false;  // a form the base model already has
  bool undecided = false;  // the held-out data cannot judge it (Decision::CannotDecide)
  FormScore score;
  double column_r2 = 0;    // scenery_feature on one scenery: its score over the column groups
  bool scenery_checked = false;  // score.r2 is then the lower of column_r2 and the crossed split's
  Decision decision = Decision::NotTried;
  std::string reason;  // in words a user acts on
  // The column score's prediction per pooled cell and its MAE, as score_form with keep_corrected
  // gives them for `refit_folds`: kept for the candidates of the best-ranked feature of a lookup
  // base, whose refit reads them instead of scoring the form again.
  std::vector<double> refit_corrected;
  double refit_mae = 0;
  bool kept = false;
  const std::vector<Fold>* refit_folds = nullptr;
  std::string name() const { return form_name(form, per_row); }
};

// A scenery_feature's candidate on scans of one scenery (p.azimuth_scenery in use): scored again
// across classes x row blocks in the same columns, and k.score becomes the lower of the two (the
// column score kept in k.column_r2). Any other candidate is left as it is.
void check_across_scenery(Candidate& k, const Pooled& p, size_t feature, const std::vector<double>& edges,
                          const std::vector<double>& fine, const std::vector<double>& rc);

struct Refit {
  std::string method;
  double mae = 0;
  bool addable = true;  // false: measured and reported only
};

struct RoundResult {
  std::string split, group_by;
  std::string azimuth_group_by;  // azimuth's cross-fit when not group_by ("" otherwise)
  int half_width = 0, folds = 1;
  double scenery_correlation = 0, time_block_correlation = 0;
  Errors before, after, tried;
  double lookup_before = 0;
  std::array<double, 2> interval{0, 0};
  std::vector<Candidate> candidates;   // every feature x form, best first
  std::vector<FeatureScore> ranking;   // best form per feature not used by the base, best first
  std::vector<std::string> ranking_form;  // the best form of each ranked feature
  std::vector<double> ranking_mae;        // and the held-out MAE of the refit it implies
  std::vector<FeatureScore> used;
  std::vector<FeatureScore> undecided;  // best form per feature the data cannot decide on
  std::string top_feature, top_form;
  bool candidate = false, added = false;
  std::string not_tried_why;  // why the top feature is not tried although above the threshold
  std::string method = "none";
  std::vector<Refit> refits;
  std::string rejected_why;
  std::vector<double> seeds_before, seeds_after, seeds_tried;
  FittedForm effect_table;             // the chosen form, fitted on every pooled cell
  std::map<std::string, BinnedTable> residual_tables;  // each feature's additive table, for the plot
  std::string plot;
};

nlohmann::json to_json(const RoundResult& r, const IntensityLoopOptions& o);
// A round's entry of "rounds": added effect, method, top feature, before, after, the change.
nlohmann::json round_summary(const nlohmann::json& round);

}  // namespace lidarsim::qualify::intensity_detail
