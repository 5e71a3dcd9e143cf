#pragma once
// The closed loop on the return rate (docs/returns.md, "The loop on the return rate"):
// residuals of the binary outcome "the beam returned" on the cells pgm::return_target says had
// geometry, against every feature a cell offers, judged on held-out scans.
//
//   base       the return model (sensor::ReturnModel, laser x 5 m range x class) fitted on the
//              reference cells; reference cells of a scan that is held out in a fold are left
//              out of that fold's base (the campaign's reference is the target's own scans before
//              the planted effect: see bench/loop_campaign_returns.cpp).
//   folds      whole groups of scans (drives; each scan its own group unless given), round-robin
//              into up to `folds` folds. The table
//              has no spatial context and the held-out target is computed from the held-out scan
//              alone, so no fit cell reaches a held-out one: the split cannot leak. Features fixed
//              to the sensor (laser, azimuth) are seen in every scan, so scan folds judge them.
//   candidates per feature (laser, range, class, material, azimuth, height) a multiplier table
//              p' = m(bin) p and a window (one multiplier over a contiguous range of fine bins,
//              circular for azimuth), plus "class x range": one class's returns multiplied
//              beyond a range (the best class and step on the fit cells). Each is fitted on the
//              fit folds only (against that fold's base) and predicts the held-out scans.
//   judged     by the held-out Bernoulli deviance, score = 1 - D(candidate) / D(base) pooled over
//              the folds; interval and a selection-aware bound from a single-step max-T bootstrap
//              over the whole family (blocks = 64-column sectors of each held-out scan, drawn
//              together for every candidate). The best candidate is added when its bound is above
//              0 and its score above `min_gain`; otherwise the report says why not.
#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "pgm/beam_layout.h"
#include "pgm/polar_grid_map.h"
#include "pgm/return_target.h"
#include "qualify/returns/term_form.h"
#include "sensor/return_model.h"

namespace lidarsim::qualify {

// One geometry cell (Return or Drop) of a scan.
struct ReturnCell {
  int scan = 0;         // scan id (unique over the loop's input)
  int row = 0, col = 0;
  float range = 0;      // measured (returned) or estimated (drop), m
  int class_id = 0;     // measured or imputed
  int material = 0;     // pgm::default_material(class_id)
  float height = 0;     // sensor-frame z = range x sin(row elevation), m
  float azimuth_deg = 0;  // column centre, 0-360
  bool returned = false;
};

// The geometry cells of a target (scan id `scan`).
std::vector<ReturnCell> return_cells(const pgm::ReturnTarget& target, const pgm::BeamLayout& layout, int scan);

// Feature names the loop knows, in its order.
const std::vector<std::string>& return_loop_features();  // laser, range, class, material, azimuth, height, class x range

struct ReturnLoopOptions {
  int folds = 5;              // at most this many scan folds (fewer when there are fewer scans)
  double prior = 20;          // the base table's shrinkage (sensor::ReturnModel::fit)
  double shrink = 20;         // a multiplier's pseudo returns towards 1
  double min_gain = 0.002;    // smallest held-out deviance cut (share of the base's) that is added
  double level = 0.95;        // one-sided level of the selection-aware bound
  int replicates = 400;       // bootstrap replicates
  int sector_columns = 64;    // bootstrap block width in columns
  std::uint64_t seed = 23;
  // Scan id -> group (a drive / place): folds are whole groups. Empty = every scan its own group.
  // Consecutive scans of one drive see the same scenery at the same azimuth, so scan folds of one
  // drive let a scenery pattern pass for a sensor-fixed (azimuth) effect; groups of other drives
  // cannot.
  std::vector<int> scan_group;
  std::uint64_t fold_seed = 0;  // 0: groups go to folds round-robin in order; else shuffled by this seed
};

struct ReturnCandidate {
  std::string feature;
  TermForm form = TermForm::table;
  double score = 0;           // held-out deviance cut, share of the base's
  double se = 0, lower = 0, upper = 0;  // bootstrap standard error and 95 % interval
  double selection_lower = 0;           // the max-T bound over the family
  std::string decision, reason;
  nlohmann::json fitted;      // the effect fitted on every target cell (bins / window / class + step)
  sensor::ReturnKey key = sensor::ReturnKey::Laser;
  std::vector<float> factor;  // the same as multipliers per key
};

struct ReturnLoopResult {
  int scans = 0, groups = 0, folds = 0;
  long long cells = 0, returns = 0;
  double deviance_before = 0, deviance_after = 0;  // held-out, per cell
  double critical = 0;                             // max-T critical value
  std::vector<ReturnCandidate> candidates;         // ranked by score
  int added = -1;                                  // index into candidates, -1 = none
  std::string added_feature;                       // "" = none
  // Per target cell (in input order), its held-out probability before and after.
  std::vector<float> p_before, p_after;
  std::vector<int> fold_of_scan;                   // scan id -> fold (-1: not a target scan)
  // The base fitted on every reference cell, with the added effect as a multiplier term.
  sensor::ReturnModel model;
};

// The loop: `target` = cells of the place examined; `reference` = cells the base is fitted on
// (same beam layout; a reference cell whose scan id is a held-out target scan is left out of that
// fold's base). Throws when the target has fewer than 2 scans or the reference is empty.
ReturnLoopResult loop_returns(const std::vector<ReturnCell>& target, const std::vector<ReturnCell>& reference,
                              const pgm::BeamLayout& layout, const ReturnLoopOptions& options = {});

// Held-out Bernoulli deviance per cell of probabilities p on the target's outcomes.
double mean_deviance(const std::vector<ReturnCell>& target, const std::vector<float>& p);

nlohmann::json to_json(const ReturnLoopResult& r);
std::string to_markdown(const ReturnLoopResult& r, const std::string& command);

// `lidar-qualify loop returns --place NAME=FORMAT:DIR ... --target NAME --report R.json`.
int run_loop_returns(int argc, char** argv);

// ---- planted effects (the campaign and the tests) ----
// A dropout planted on measured scans: each return is kept with probability keep(cell), drawn by
// sensor::return_draw(seed, scan, cell) (deterministic, no state).
enum class PlantedReturnFamily { LaserDropout, ClassBeyondRange, AzimuthWindow, Control };
const std::vector<PlantedReturnFamily>& all_planted_return_families();
std::string to_string(PlantedReturnFamily f);
PlantedReturnFamily planted_return_family_from_string(const std::string& name);

struct PlantedReturnEffect {
  PlantedReturnFamily family = PlantedReturnFamily::Control;
  std::vector<std::string> accepted;  // loop feature names that count as naming it (empty: control)
  std::vector<double> row_keep;       // LaserDropout: keep probability per row (1 elsewhere)
  int class_id = -1;                  // ClassBeyondRange
  double range_m = 0, keep = 1;       // ClassBeyondRange: beyond range_m; AzimuthWindow, ClassBeyondRange: keep
  double azimuth_start_deg = 0, azimuth_width_deg = 0;  // AzimuthWindow, [start, start + width) mod 360
  nlohmann::json parameters;
  double keep_at(int row, double range_m, int class_id, double azimuth_deg) const;
};

// Draws one effect of `family` from `seed`: LaserDropout 1-4 random lasers kept at 0.3-0.8;
// ClassBeyondRange one class with >= 2 % of the returns (classes given by their return counts)
// kept at 0.3-0.7 beyond a range drawn between its returns' 20th and 70th percentile;
// AzimuthWindow a window 20-90 deg wide anywhere, kept at 0.4-0.8.
PlantedReturnEffect draw_planted_returns(PlantedReturnFamily family, std::uint64_t seed, int rows,
                                         const std::vector<std::vector<float>>& class_ranges);

// Drops the returns of a measured map with the effect: a return is kept when
// sensor::return_draw(seed, scan, cell) < keep; a dropped cell becomes empty as
// sensor::apply_return_model leaves it. Returns the number dropped. Needs range, mask and class.
int plant_returns(pgm::PolarGridMap& map, const PlantedReturnEffect& effect, std::uint64_t seed, std::uint64_t scan);

}  // namespace lidarsim::qualify
