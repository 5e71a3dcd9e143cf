#include "qualify/objects/object_simulated.h"

#include <algorithm>

#include "sensor/kpi_manager.h"

namespace lidarsim::qualify::obj {

namespace {

// One number per truth object the KPI manager produces with `model` (read from its injection),
// keyed by (sequence, frame, id). A fresh manager per sequence: track ages restart. The manager
// sees ids made unique across sequences (as sensor::resimulate does), so track 3 of one sequence
// does not take the same random streams as track 3 of another.
template <class Read>
std::map<std::array<int, 3>, double> simulated_per_object(const std::vector<sensor::CalibrationSequence>& seqs,
                                                          const std::vector<int>& which, const sensor::KpiModel& model,
                                                          std::uint64_t seed, Read read) {
  std::map<std::array<int, 3>, double> out;
  std::vector<sensor::Object> truth, reported;
  for (int s : which) {
    sensor::KpiManager kpi(model, seed);
    const auto& cs = seqs.at(s);
    for (size_t f = 0; f < cs.frames.size(); ++f) {
      truth = cs.frames[f].truth;
      for (auto& o : truth) o.id = s * 100000 + o.id;
      kpi.apply(truth, reported);
      for (const auto& inj : kpi.injections())
        if (inj.modelled) out[{s, static_cast<int>(f), cs.frames[f].truth[inj.truth_index].id}] = read(inj);
    }
  }
  return out;
}

}  // namespace

std::map<std::array<int, 3>, double> simulated_mean_error(const std::vector<sensor::CalibrationSequence>& seqs,
                                                          const std::vector<int>& which, sensor::KpiModel model,
                                                          sensor::KpiParam p, std::uint64_t seed) {
  for (auto& [name, c] : model.classes)
    for (auto& e : c.errors) {
      std::fill(e.sigma.begin(), e.sigma.end(), 0.0);
      e.track_std = 0;
    }
  return simulated_per_object(seqs, which, model, seed,
                              [p](const sensor::KpiInjection& inj) { return inj.error[static_cast<int>(p)]; });
}

std::map<std::array<int, 3>, double> simulated_error_draw(const std::vector<sensor::CalibrationSequence>& seqs,
                                                          const std::vector<int>& which, const sensor::KpiModel& model,
                                                          sensor::KpiParam p, std::uint64_t seed) {
  return simulated_per_object(seqs, which, model, seed,
                              [p](const sensor::KpiInjection& inj) { return inj.error[static_cast<int>(p)]; });
}

std::map<std::array<int, 3>, double> simulated_detection_probability(
    const std::vector<sensor::CalibrationSequence>& seqs, const std::vector<int>& which, const sensor::KpiModel& model,
    std::uint64_t seed) {
  return simulated_per_object(seqs, which, model, seed,
                              [](const sensor::KpiInjection& inj) { return inj.detection_probability; });
}

}  // namespace lidarsim::qualify::obj
