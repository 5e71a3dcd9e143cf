#include "qualify/objects/object_distribution.h"

#include "qualify/similarity.h"

namespace lidarsim::qualify::obj {

std::vector<PerClass<double>> held_out_intersections_all(const TrackingData& data, const std::array<Fold, 2>& folds,
                                                              const std::array<sensor::KpiModel, 2>& models,
                                                              std::uint64_t seed, int seeds) {
  constexpr int nt = kDetectionTarget;  // the error targets
  std::vector<double> sim[2][nt][kObjectClassCount], meas[2][nt][kObjectClassCount];
  sensor::FitOptions opt;
  for (int k = 0; k < 2; ++k) {
    for (const ObjectRecord& r : folds[k].held_set.records)
      if (r.detected && r.cls >= 0 && r.cls < kObjectClassCount)
        for (int t = 0; t < nt; ++t) meas[k][t][r.cls].push_back(r.value[t]);
    opt.range_bin_edges = models[k].range_bin_edges;
    opt.visibility_bin_edges = models[k].visibility_bin_edges;
    in_seed_order(
        seeds,
        [&](int q) {
          const auto simulated = sensor::resimulate(data.calib, models[k], seed + q);
          return collect_objects(data, folds[k].held_idx, &simulated, opt);
        },
        [&](int, const ObjectSet& s) {
          for (const ObjectRecord& r : s.records)
            if (r.detected && r.cls >= 0 && r.cls < kObjectClassCount)
              for (int t = 0; t < nt; ++t) sim[k][t][r.cls].push_back(r.value[t]);
        });
  }
  std::vector<PerClass<double>> out(nt, {-1, -1, -1});
  for (int t = 0; t < nt; ++t)
    for (int c = 0; c < kObjectClassCount; ++c) {
      if (long(meas[0][t][c].size()) < kDistributionMinSamples || long(meas[1][t][c].size()) < kDistributionMinSamples ||
          sim[0][t][c].empty() || sim[1][t][c].empty())
        continue;
      std::vector<double> m = meas[0][t][c], s = sim[0][t][c];
      m.insert(m.end(), meas[1][t][c].begin(), meas[1][t][c].end());
      s.insert(s.end(), sim[1][t][c].begin(), sim[1][t][c].end());
      out[t][c] = histogram_intersection(s, m);
    }
  return out;
}

}  // namespace lidarsim::qualify::obj
