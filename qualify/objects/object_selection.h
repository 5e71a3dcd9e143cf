#pragma once
// The object loop's selection-aware bound (internal to qualify/). Every candidate (feature x
// target x form, some 200 bias forms and 180 spread forms) is scored on the held-out folds, and
// the best ones are then judged on the same held-out data. Each candidate's own held-out score is
// an honest estimate, but the best of 200 is not: on data without any effect the top one's own
// 95 % interval lies above 0 far more often than 1 run in 40 (the winner's curse; measured on the
// campaign's controls, bench/loop_campaign_objects.cpp). The bound here holds whichever candidate
// the scores pick: a single-step max-T bootstrap (Romano & Wolf 2005) over a family of candidates:
//   - one replicate resamples the held-out track blocks once for every candidate of the family
//     (the blocks of one fold set drawn together, different fold sets independently), so the
//     correlation between candidates (speed and longitudinal velocity, a table and a window of
//     one feature) is kept and correlated candidates cost little;
//   - each candidate's score is studentised by its bootstrap standard error se;
//   - c = the `level` quantile over replicates of the largest studentised rise over the family;
//   - the bound is score - c x se.
// With a single candidate c is about 1.96 and the bound about the lower end of its 95 % interval.
#include <array>
#include <cstdint>
#include <vector>

#include "qualify/objects/object_candidates.h"

namespace lidarsim::qualify::obj {

// The simultaneous lower bounds of the candidates `members` (indices into cands), written to
// Candidate::selection_lower, and the critical value c returned (0 for an empty family). A
// candidate's score statistic is score_of_sums (its kind's) over Candidate::blocks. Deterministic
// in seed.
double selection_aware_bounds(std::vector<Candidate>& cands, const std::vector<int>& members, double level = 0.975,
                              int replicates = 1000, std::uint64_t seed = 23);

}  // namespace lidarsim::qualify::obj
