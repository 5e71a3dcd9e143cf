#pragma once
// The object loop's distribution check (internal to qualify/): does a term make the re-simulated
// held-out distribution of its KPI more like the measured one? A lower mean residual is not
// enough: a term that explains the mean but leaves the noise too wide or too narrow for a class
// moves that class's simulated distribution away from the measured one.
#include <algorithm>
#include <array>
#include <cstdint>
#include <vector>

#include "qualify/objects/object_folds.h"

namespace lidarsim::qualify::obj {

inline constexpr long kDistributionMinSamples = 30;  // measured, per class, in each fold's held-out part

// Per error target and class ([target][class]): the histogram intersection
// (qualify/similarity.h) of the simulated errors against the measured ones on the folds' held-out
// sequences: models[k] (fitted on fold k's fit sequences) re-simulated on data.calib with
// `seeds` seeds (seed, seed + 1, ...; LoopOptions::distribution_seeds: with too few, a model with
// per-track constants pays Monte Carlo noise, objects.h), its matched errors on fold k's held-out sequences
// pooled over both folds and all seeds against the measured errors of the same sequences pooled
// over both folds. -1 for a class with fewer than kDistributionMinSamples measured samples in
// either fold.
// make(q) for q in [0, n), a few at a time in parallel, and use(q, made) in order of q on the
// calling thread: simulations of independent seeds, whose samples must not depend on the thread
// count. make must be safe to run concurrently.
template <typename Make, typename Use>
void in_seed_order(int n, Make make, Use use) {
  constexpr int kChunk = 8;
  std::vector<decltype(make(0))> made(kChunk);
  for (int q0 = 0; q0 < n; q0 += kChunk) {
    const int m = std::min(kChunk, n - q0);
#pragma omp parallel for schedule(dynamic)
    for (int i = 0; i < m; ++i) made[i] = make(q0 + i);
    for (int i = 0; i < m; ++i) use(q0 + i, made[i]);
  }
}

std::vector<PerClass<double>> held_out_intersections_all(const TrackingData& data, const std::array<Fold, 2>& folds,
                                                const std::array<sensor::KpiModel, 2>& models, std::uint64_t seed,
                                                int seeds);

}  // namespace lidarsim::qualify::obj
