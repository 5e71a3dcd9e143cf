#include "qualify/objects/object_selection.h"

#include <algorithm>
#include <cmath>
#include <map>

#include "common/error.h"
#include "qualify/similarity.h"

namespace lidarsim::qualify::obj {

double selection_aware_bounds(std::vector<Candidate>& cands, const std::vector<int>& members, double level,
                              int replicates, std::uint64_t seed) {
  if (members.empty()) return 0;
  if (replicates < 10) throw Error("selection-aware bounds: need at least 10 replicates, got " + std::to_string(replicates));
  // The fold sets' block counts: candidates of one fold set share its block indices.
  std::map<int, size_t> nblocks;
  for (int i : members) {
    const Candidate& c = cands[i];
    const auto [it, fresh] = nblocks.try_emplace(c.fold_set, c.blocks.size());
    if (!fresh && it->second != c.blocks.size())
      throw Error("selection-aware bounds: candidates of fold set " + std::to_string(c.fold_set) +
                  " disagree on the number of track blocks");
  }
  SplitMix rng(seed);
  std::map<int, std::vector<int>> counts;  // per fold set: how often each block is drawn
  std::vector<std::vector<double>> reps(members.size(), std::vector<double>(replicates));
  for (int b = 0; b < replicates; ++b) {
    for (auto& [set, n] : nblocks) {
      auto& k = counts[set];
      k.assign(n, 0);
      for (size_t j = 0; j < n; ++j) ++k[rng.next() % n];
    }
    for (size_t m = 0; m < members.size(); ++m) {
      const Candidate& c = cands[members[m]];
      const auto& k = counts[c.fold_set];
      std::array<double, 3> s{0, 0, 0};
      for (size_t j = 0; j < c.blocks.size(); ++j)
        if (k[j])
          for (int q = 0; q < 3; ++q) s[q] += k[j] * c.blocks[j][q];
      reps[m][b] = score_of_sums(c.kind, s);
    }
  }
  // Each candidate's bootstrap standard error, and per replicate the largest studentised rise.
  std::vector<double> se(members.size(), 0.0), rise(replicates, -1e300);
  for (size_t m = 0; m < members.size(); ++m) {
    double mean = 0, var = 0;
    for (double v : reps[m]) mean += v / replicates;
    for (double v : reps[m]) var += (v - mean) * (v - mean) / (replicates - 1);
    se[m] = std::sqrt(var);
    if (!(se[m] > 1e-12)) continue;  // a score that no resampling moves has nothing to correct
    const double point = cands[members[m]].score;
    for (int b = 0; b < replicates; ++b) rise[b] = std::max(rise[b], (reps[m][b] - point) / se[m]);
  }
  std::sort(rise.begin(), rise.end());
  const double c = std::max(0.0, rise[static_cast<size_t>(level * (replicates - 1))]);
  for (size_t m = 0; m < members.size(); ++m) {
    Candidate& cand = cands[members[m]];
    cand.selection_lower = cand.score - c * se[m];
    cand.selection_critical = c;
    cand.selection_family = static_cast<int>(members.size());
  }
  return c;
}

}  // namespace lidarsim::qualify::obj
