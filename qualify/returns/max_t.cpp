#include "qualify/returns/max_t.h"

#include <algorithm>
#include <cmath>

#include "common/error.h"
#include "qualify/similarity.h"

namespace lidarsim::qualify {

MaxTScores block_max_t(const std::vector<double>& base, const std::vector<std::vector<double>>& candidate,
                       int replicates, double level, std::uint64_t seed) {
  const int nc = static_cast<int>(candidate.size()), B = static_cast<int>(base.size());
  if (replicates < 1) throw Error("max-T bootstrap: at least 1 replicate, got " + std::to_string(replicates));
  for (const auto& c : candidate)
    if (c.size() != base.size()) throw Error("max-T bootstrap: a candidate has another block count than the base");
  MaxTScores out;
  double Db = 0;
  for (double v : base) Db += v;
  out.score.assign(nc, 0.0);
  for (int j = 0; j < nc; ++j) {
    double Dc = 0;
    for (double v : candidate[j]) Dc += v;
    out.score[j] = Db > 0 ? 1 - Dc / Db : 0;
  }
  if (B == 0) {
    out.se.assign(nc, 0.0);
    return out;
  }
  SplitMix rng(seed);
  std::vector<std::vector<double>> reps(nc, std::vector<double>(replicates));
  std::vector<int> cnt(B);
  for (int b = 0; b < replicates; ++b) {
    std::fill(cnt.begin(), cnt.end(), 0);
    for (int k = 0; k < B; ++k) ++cnt[rng.next() % B];
    double sb = 0;
    for (int k = 0; k < B; ++k) sb += cnt[k] * base[k];
    for (int j = 0; j < nc; ++j) {
      double sc = 0;
      for (int k = 0; k < B; ++k) sc += cnt[k] * candidate[j][k];
      reps[j][b] = sb > 0 ? 1 - sc / sb : 0;
    }
  }
  out.se.assign(nc, 0.0);
  std::vector<double> rise(replicates, -1e300);
  for (int j = 0; j < nc; ++j) {
    double mean = 0, var = 0;
    for (double v : reps[j]) mean += v / replicates;
    for (double v : reps[j]) var += (v - mean) * (v - mean) / std::max(1, replicates - 1);
    out.se[j] = std::sqrt(var);
    if (!(out.se[j] > 1e-12)) continue;
    for (int b = 0; b < replicates; ++b) rise[b] = std::max(rise[b], (reps[j][b] - out.score[j]) / out.se[j]);
  }
  std::sort(rise.begin(), rise.end());
  out.critical = std::max(0.0, rise[static_cast<std::size_t>(level * (replicates - 1))]);
  return out;
}

}  // namespace lidarsim::qualify
