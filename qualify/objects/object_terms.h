#pragma once
// The effect forms the object loop fits on a fold's fit sequences and adds to the KPI model
// (internal to qualify/): a per-class binned table on a feature, refitted jointly with the
// model's own cells (backfitting), and the refitted KPI model that carries it as a
// sensor::ConditionalTerm.
#include <array>
#include <cstdint>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "qualify/objects/object_folds.h"

namespace lidarsim::qualify::obj {

// The conditional term: a bias table on the feature per class (the KPI model is per class),
// the pooled table for classes with fewer than 200 fit samples.
struct ClassTables {
  BinnedTable pooled;
  PerClass<BinnedTable> per_class;
  PerClass<bool> own{};
  double operator()(int cls, double x) const {
    return cls >= 0 && cls < kObjectClassCount && own[cls] ? per_class[cls](x) : pooled(x);
  }
};

ClassTables fit_class_tables(const std::vector<double>& x, const std::vector<double>& r, const std::vector<int>& cls,
                             int bins);

// The added conditional term refitted together with the model's own cells (backfitting): the
// range-bin means of an error, or the [range bin][visibility bin] detection probabilities. On the
// fit split those cells have absorbed whatever part of the hidden effect correlates with them, so
// the table alone would be fitted against a distorted residual (and, for detection, come out
// attenuated). r ~ d[class][cell] + table(class, feature), alternating 4 passes.
struct Refit {
  ClassTables table;
  std::map<std::pair<int, int>, double> d;
  // 0 for errors: a cell's offset is its mean residual. For detection the base's cells are Beta-
  // shrunk (sensor::kDetectionPriorObjects, this value): a cell then takes back only the table's
  // mean over it, over (n + this). The refit shrinks as the base does, so a candidate is judged on
  // its effect and not on the difference between a raw and a shrunk cell.
  double cell_prior = 0;
  // After shrink_by_track_bootstrap: each bin's factor (fitted value x factor = the value kept) and
  // its bootstrap standard error, laid out like `table`; empty value vectors when not shrunk.
  ClassTables factor, se;
  // Detection only (rate_gain, object_rate_gain.h): a gain per bin of the feature on the cell's
  // probability, applied before the table's shift (empty pooled.value: none).
  ClassTables gain;
  bool has_gain() const { return !gain.pooled.value.empty(); }
  // mean_relative_line (backfit_relative_line): the kObjectFeatures index of the object's own size
  // that the table's value is a share of, so the term is table(cls, x) x that size; -1: absolute.
  int relative = -1;
  // The term at a record: cell offset + table (x the record's relative_to value s when relative).
  double at(int cls, int rb, double x, double s) const {
    const auto it = d.find({cls, rb});
    return (it == d.end() ? 0.0 : it->second) + table(cls, x) * (relative >= 0 ? s : 1.0);
  }
  // An absolute term only: a relative term needs each record's size (at; relative_values).
  double operator()(int cls, int rb, double x) const;
};

// What each record of `s` multiplies f's table by: the relative_to column, or 1 for an absolute term.
std::vector<double> relative_values(const Split& s, const Refit& f);

Refit backfit(const std::vector<double>& x, const std::vector<double>& r, const std::vector<int>& cls,
              const std::vector<int>& rb, int bins, double cell_prior = 0);

// A window (or step) of x with fitted edges: the contiguous run of up to `fine_bins` equal-count
// bins of the fit split whose mean of y differs most from the rest (between-groups sum of
// squares), at least `min_side` samples inside and outside. Returned as a table over the run's
// edges: 0 outside, the in-minus-out difference (shrunk by n / (n + 5)) inside. Without a run
// that qualifies: one bin of 0.
BinnedTable fit_window(const std::vector<double>& x, const std::vector<double>& y, int fine_bins = 40,
                       long min_side = 30);
// backfit with the window (pooled over classes) in place of the per-class tables.
Refit backfit_window(const std::vector<double>& x, const std::vector<double>& r, const std::vector<int>& cls,
                     const std::vector<int>& rb, int fine_bins = 40, double cell_prior = 0);

// A straight line in x per class (pooled for classes with fewer than 200 samples), y = a + b x by
// least squares on x clamped to its 1-99 % quantiles [q1, q99], carried as a table of kLineBins
// equal-width bins over [q1 - s, q99 + s] (s = q99 - q1), each holding the line at its centre, flat
// beyond. A table of equal-count bins is flat beyond the fit split's range, so an effect
// proportional to a feature (a position lag x velocity, a scale error x size) fitted where the
// feature spans little (a sequence of parked cars) misses where it spans more; a line carries it
// there with two numbers per class.
inline constexpr int kLineBins = 64;
BinnedTable fit_line_table(const std::vector<double>& x, const std::vector<double>& y);
ClassTables fit_class_lines(const std::vector<double>& x, const std::vector<double>& y, const std::vector<int>& cls);
// The table fit_line_table lays out for the line a + b x fitted on x clamped to [q1, q99].
BinnedTable line_table(double a, double b, double q1, double q99, const std::vector<double>& x);
// backfit with the lines in place of the per-class tables.
Refit backfit_line(const std::vector<double>& x, const std::vector<double>& r, const std::vector<int>& cls,
                   const std::vector<int>& rb, double cell_prior = 0);

// A relative line (object_terms_relative.cpp): an error that is a share of the object's own size
// (`size`: its length, width or height, > 0), the share a straight line in x, per class (pooled for
// classes with fewer than 200 samples): y ~ s (a + b x) by least squares (y / s on x with weights
// s^2), x clamped to its 1-99 % quantiles, laid out as fit_line_table's table of the share. A table
// or line of the absolute error holds only the class's mean share x its mean size, so it misses on
// every object whose size differs from the mean (a pedestrian pooled with cars, a van among cars).
BinnedTable fit_relative_line_table(const std::vector<double>& x, const std::vector<double>& y,
                                    const std::vector<double>& size);
ClassTables fit_class_relative_lines(const std::vector<double>& x, const std::vector<double>& y,
                                     const std::vector<double>& size, const std::vector<int>& cls);
// backfit with the relative lines: r ~ d[class][cell] + size x line(class, x); Refit::relative set
// to `relative_feature` (the kObjectFeatures index of `size`).
Refit backfit_relative_line(const std::vector<double>& x, const std::vector<double>& r, const std::vector<double>& size,
                            const std::vector<int>& cls, const std::vector<int>& rb, int relative_feature);
// The kObjectFeatures index of target t's own dimension (length: size, width: box_width, height:
// box_height), -1 for the other targets.
int own_dimension(int t);

// Shrinks a fitted bias term (table or window) towards 0 by its own sampling uncertainty, so that
// a bin carried by a few tracks is trusted less than one carried by hundreds. The bins' standard
// errors come from a bootstrap over whole tracks of the fit data (`track`: one id per record;
// frames of a track are not independent): each replicate draws the tracks with replacement and
// refits the term's values with its edges kept (the same backfitting with the cell offsets as the
// fit, weights = draw counts). Each table (pooled, per class) is then partially pooled towards 0
// (empirical Bayes, normal prior of variance tau^2 on the bins): tau^2 = mean over the table's bins
// of (value^2 - se^2), at least 0, and each bin x tau^2 / (tau^2 + se^2). A table whose bins are no
// larger than their noise is shrunk to 0; a bin as large as many standard errors keeps nearly all
// of it; for a window (one bin) this is max(0, 1 - se^2 / value^2). The cell offsets are refitted
// against the shrunk table. towards_pooled: each class's own table is pooled towards the (shrunk)
// pooled table instead of 0 (prior mean of a class bin = the pooled table's mean over the class's
// records in it; tau^2 from the deviations), so a class with few tracks borrows the shape the
// other classes show. `window`: f came from backfit_window (only its inside bin is a value).
// Deterministic (fixed seed).
void shrink_by_track_bootstrap(Refit& f, const std::vector<double>& x, const std::vector<double>& r,
                               const std::vector<int>& cls, const std::vector<int>& rb, const std::vector<int>& track,
                               bool window, bool towards_pooled = false, int replicates = 100,
                               std::uint64_t seed = 7);

// A mean term on an error explains part of the spread the base model's noise was fitted to carry:
// without this the refitted model's errors come out too wide (term + the old noise). Per class,
// v = variance of the term's values (table + cell offsets) over the fit records, V = variance of
// the winsorised fit residual; the term's part constant along a track (all of it for a feature
// constant along a track, such as size; else the variance of its per-track means) comes out of the
// per-track constant first (track_std^2 - that, at least 0), the rest out of sigma
// (sigma x sqrt(1 - v_rest / V), at least 0.2 of it). The noise's shape, AR(1) and innovation, is
// refitted (sensor::fit_error_model) on the fit records' errors minus the term (classes with at
// least 40 of them), so correlation along a track or tails the term carried leave the noise.
void shrink_noise_for_term(sensor::KpiModel& m, const Refit& ref, int t, const std::string& feature, const Split& fit,
                           const Winsor& w, int nvis, PerClass<bool> classes = {true, true, true});

// The detection probability the KPI manager uses with a rate term (with_term): the cell's
// probability p plus the refitted cell offset, clamped to [0, 1], times the term's gain (when it has
// one), plus the term's bias, clamped again.
double refit_probability(const Refit& ref, int cls, int cell, double x, double p);

// Target t's term on feature f fitted on fold k's fit residuals (winsorised).
Refit refit_on(const Fold& k, int t, int f, int nvis, int bins);

// The base model with the loop's range-bin offsets added to target t's means (detection: to the
// detection probabilities of the range x visibility cell, clamped to [0, 1]) and the feature
// table as its conditional term (on that error, or on detection probability).
// `classes`: the classes that get the term (the others keep the base's model of t).
sensor::KpiModel with_term(const sensor::KpiModel& base, const Refit& ref, int t, const std::string& feature,
                           int nvis, PerClass<bool> classes = {true, true, true});

// with_term, and for an error target the noise shrunk for the classes that get the term
// (shrink_noise_for_term on the fit split and its winsor limits).
sensor::KpiModel with_term_and_noise(const sensor::KpiModel& base, const Refit& ref, int t, const std::string& feature,
                                     int nvis, const Split& fit, const Winsor& w,
                                     PerClass<bool> classes = {true, true, true});

}  // namespace lidarsim::qualify::obj
