#pragma once
// Held-out scores of a family of candidates against a base, with a selection-aware bound: a
// single-step max-T block bootstrap (shared by the loops on the return rate and on range noise).
// Inputs are a loss summed per bootstrap block (a sector of a scan, say) for the base and for each
// candidate; score = 1 - L(candidate) / L(base) over all blocks. Each replicate draws the blocks
// with replacement once and scores every candidate on the same draw, so the critical value is
// that of the family's best chance rise: a candidate is kept when score - critical x se > 0.
#include <cstdint>
#include <vector>

namespace lidarsim::qualify {

struct MaxTScores {
  std::vector<double> score, se;  // per candidate
  double critical = 0;            // the level-quantile of max_j (replicate_j - score_j) / se_j, >= 0
};

MaxTScores block_max_t(const std::vector<double>& base, const std::vector<std::vector<double>>& candidate,
                       int replicates, double level, std::uint64_t seed);

}  // namespace lidarsim::qualify
