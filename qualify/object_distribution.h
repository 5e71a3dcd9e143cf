#pragma once
// The object loop's distribution check (internal to qualify/): does a term make the re-simulated
// held-out distribution of its KPI more like the measured one? A lower mean residual is not
// enough: a term that explains the mean but leaves the noise too wide or too narrow for a class
// moves that class's simulated distribution away from the measured one.
#include <array>
#include <cstdint>
#include <vector>

#include "qualify/object_folds.h"

namespace lidarsim::qualify::obj {

// Default seeds of the check (LoopOptions::distribution_seeds): a model with per-track constants
// draws one offset per track and seed, and the Monte Carlo noise of too few draws lowers its
// intersection (objects.h, qualify_objects); with 32 seeds the check kept terms that 256 reject.
inline constexpr int kDistributionSeeds = 256;
inline constexpr long kDistributionMinSamples = 30;  // measured, per class, in each fold's held-out part

// Per error target and class ([target][class]): the histogram intersection
// (qualify/similarity.h) of the simulated errors against the measured ones on the folds' held-out
// sequences: models[k] (fitted on fold k's fit sequences) re-simulated on data.calib with
// `seeds` seeds (seed, seed + 1, ...), its matched errors on fold k's held-out sequences
// pooled over both folds and all seeds against the measured errors of the same sequences pooled
// over both folds. -1 for a class with fewer than kDistributionMinSamples measured samples in
// either fold.
std::vector<std::array<double, 3>> held_out_intersections_all(const TrackingData& data, const std::array<Fold, 2>& folds,
                                                const std::array<sensor::KpiModel, 2>& models, std::uint64_t seed,
                                                int seeds = kDistributionSeeds);

}  // namespace lidarsim::qualify::obj
