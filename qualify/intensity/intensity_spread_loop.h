#pragma once
// The closed loop on the spread of intensity (docs/intensity.md, "The loop on the spread of
// intensity"): where does the scatter of measured intensity around the model's mean differ from
// what a spread model by range alone says, and by how much.
//
//   residual   e = measured intensity - the class x range lookup's mean, the lookup fitted out of
//              fold: the intensity loop's rotated guarded folds (intensity_internal.h make_folds),
//              so every cell's mean comes from a lookup that saw none of its columns.
//   judged     by the range-noise loop's machinery (range_noise_loop.h) on y = log|e|: the base a
//              log-scale per 5 m range bin, candidates a table of log-scale shifts (a spread factor
//              per bin) and a window per feature, and a spread c * range added in quadrature,
//              fitted on azimuth sectors of 3 folds and scored on the 4th with guard bands, with
//              the max-T selection-aware bound.
//   features   laser, range, class, material, azimuth, incidence, and "intensity", which here is
//              the lookup's predicted mean (a spread that grows with the signal, as shot noise
//              does): never the measured intensity, whose bins would hold |e| itself.
#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "data/dataset.h"
#include "data/planted_scans.h"
#include "sensor/range_noise.h"
#include "qualify/range_noise/range_noise_loop.h"

namespace lidarsim::qualify {

struct IntensitySpreadOptions {
  RangeLoopOptions loop;
  std::string split = "guarded";  // the intensity folds' split (data::parse_split)
  int folds = 4;                  // intensity folds (rotated guarded regions) for the out-of-fold mean
  // A checkpoint with a spread head (lidar-train --heads mean,log_scale_laplace): the residual is
  // against its mean, and its predicted log-scale is each residual's offset, so the loop finds what
  // the spread the simulation samples from lacks. Its scans must be of places it did not train on.
  std::string model;
  // Terms the model's spread carries already (infer/intensity_spread_terms.h): the loop judges
  // what the head with them lacks. Only with a model.
  std::vector<sensor::RangeNoiseTerm> spread_terms;
};

// One residual per cell with a return (every cell is held out once by the intensity folds; with
// a model, every cell with a return and a predicted scale), with the cell's features; scan = the
// frame index.
std::vector<LoopResidual> intensity_spread_residuals(const data::Dataset& ds, const IntensitySpreadOptions& o = {});

// The loop on the residuals of ds (its own cells are the reference: each spread fold's base sees
// only its fit sectors). Throws when ds has no return or lacks a channel it needs.
RangeLoopResult loop_intensity_spread(const data::Dataset& ds, const IntensitySpreadOptions& o = {});

// The range-noise loop's JSON in intensity's words (growth in intensity per metre); model: the
// residuals were against a checkpoint (IntensitySpreadOptions::model).
nlohmann::json intensity_spread_json(const RangeLoopResult& r, bool model = false);

// `lidar-qualify loop intensity-spread --semantickitti DIR --report R.json [--rounds N]`.
int run_loop_intensity_spread(int argc, char** argv);

// ---- planted spread (the campaign and the tests) ----
// intensity = the hidden base of data/planted_scans.h (albedo per class x range fall-off) +
// N(0, (sigma x factor(cell))^2): the base's noise made wider where the effect acts.
// A spread that grows with range alone is the base's own form (its range table holds it), so it is
// not a family: there is nothing to add.
enum class PlantedSpreadFamily { LaserBlock, AzimuthWindow, OneClass, Incidence, Control };
const std::vector<PlantedSpreadFamily>& all_planted_spread_families();
std::string to_string(PlantedSpreadFamily f);
PlantedSpreadFamily planted_spread_family_from_string(const std::string& name);  // throws naming the known ones

struct PlantedSpread {
  PlantedSpreadFamily family = PlantedSpreadFamily::Control;
  std::vector<std::string> accepted;    // the loop's feature names that count as naming it
  double factor = 1;                    // LaserBlock, AzimuthWindow, OneClass: the spread's factor where it acts
  int row_first = 0, row_last = -1;     // LaserBlock, inclusive
  double azimuth_start_deg = 0, azimuth_width_deg = 0;  // AzimuthWindow: [start, start + width) mod 360
  int class_id = -1;                    // OneClass
  double per_90deg = 0;                 // Incidence: factor 1 + per_90deg x incidence / 90 deg
  nlohmann::json parameters;
  // The noise's standard deviation at a cell, given the base's sigma.
  double sigma_at(double sigma, int row, double azimuth_deg, double incidence_rad, int class_id) const;
};

// Parameters drawn from `seed`: LaserBlock a block of 10-25 % of the rows at 1.6-3 x; AzimuthWindow
// 1.6-3 x over 30-120 deg anywhere; OneClass a class holding >= 5 % of the returns at 1.6-3 x;
// Incidence 1 + a x incidence / 90 deg, a in 1-2.5 (a footprint stretched at grazing angles).
PlantedSpread draw_planted_spread(PlantedSpreadFamily family, std::uint64_t seed, const data::Dataset& geometry,
                                  double sigma);

// geometry with its target replaced: the hidden base of `base` (data::draw_planted) plus Gaussian
// noise of sigma_at(base.base.sigma, ...) per cell, from `seed`.
data::Dataset plant_spread(const data::Dataset& geometry, const data::PlantedScanDraw& base, const PlantedSpread& e,
                           std::uint64_t seed);

// Against the truth: the RMS over the loop's scored residuals of (predicted log-scale - true
// log-scale of a Gaussian of sigma_at), with the loop's base (before) and with its added term
// (after). The lookup's own estimation error is in both.
struct SpreadTruth {
  double before = 0, after = 0;
  long long n = 0;
};
SpreadTruth spread_truth(const std::vector<LoopResidual>& residuals, const RangeLoopResult& r, const PlantedSpread& e,
                         double sigma);

}  // namespace lidarsim::qualify
