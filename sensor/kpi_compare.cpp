// The checks of a fitted KPI model against the measurement (sensor/kpi_fit.h): the model's
// detections re-simulated on the measured ground truth, and the two compared statistic by
// statistic. The fit itself is in sensor/kpi_fit.cpp.
#include <algorithm>
#include <iomanip>
#include <map>
#include <sstream>

#include "sensor/kpi_fit.h"
#include "sensor/kpi_manager.h"

namespace lidarsim::sensor {

double histogram_intersection(const std::vector<double>& ref, const std::vector<double>& other, int bins) {
  if (ref.size() < 2 || other.empty() || bins < 1) return 0;
  std::vector<double> sorted = ref;
  std::sort(sorted.begin(), sorted.end());
  const double lo = sorted[static_cast<size_t>(0.01 * (sorted.size() - 1))];
  const double hi = sorted[static_cast<size_t>(0.99 * (sorted.size() - 1))];
  const double width = hi > lo ? (hi - lo) / bins : 1.0;
  auto hist = [&](const std::vector<double>& v) {
    std::vector<double> h(bins + 2, 0.0);
    for (double x : v) {
      const int k = x < lo ? 0 : x >= hi ? bins + 1 : 1 + std::min(bins - 1, static_cast<int>((x - lo) / width));
      h[k] += 1.0 / v.size();
    }
    return h;
  };
  const auto a = hist(ref), b = hist(other);
  double s = 0;
  for (int k = 0; k < bins + 2; ++k) s += std::min(a[k], b[k]);
  return s;
}

std::vector<CalibrationSequence> with_truth_motion(std::vector<CalibrationSequence> seqs) {
  for (auto& cs : seqs) {
    const double dt = cs.frame_dt;
    std::map<int, std::map<int, Eigen::Vector3d>> pos;
    for (size_t f = 0; f < cs.frames.size(); ++f)
      for (const auto& o : cs.frames[f].truth) pos[o.id][static_cast<int>(f)] = o.position;
    for (size_t f = 0; f < cs.frames.size(); ++f)
      for (auto& o : cs.frames[f].truth) {
        const auto& tp = pos[o.id];
        const int fi = static_cast<int>(f);
        const auto prev = tp.find(fi - 1), next = tp.find(fi + 1);
        o.velocity.setZero();
        o.acceleration.setZero();
        if (prev != tp.end() && next != tp.end()) {
          o.velocity = (next->second - prev->second) / (2 * dt);
          o.acceleration = (next->second - 2 * o.position + prev->second) / (dt * dt);
        } else if (next != tp.end()) {
          o.velocity = (next->second - o.position) / dt;
        } else if (prev != tp.end()) {
          o.velocity = (o.position - prev->second) / dt;
        }
      }
  }
  return seqs;
}

std::vector<CalibrationSequence> resimulate(const std::vector<CalibrationSequence>& seqs, const KpiModel& model,
                                            std::uint64_t seed) {
  KpiManager kpi(model, seed);
  std::vector<CalibrationSequence> out = with_truth_motion(seqs);
  std::vector<Object> truth, reported;
  for (size_t s = 0; s < out.size(); ++s) {
    for (CalibrationFrame& fr : out[s].frames) {
      truth = fr.truth;
      // Ids unique across sequences, so each track keeps its own noise state.
      for (Object& o : truth) o.id = static_cast<int>(s) * 100000 + o.id;
      kpi.apply(truth, reported);
      fr.detections = reported;
    }
  }
  return out;
}

std::string format_comparison(const CalibrationStats& meas, const CalibrationStats& sim) {
  std::ostringstream o;
  o << std::fixed;
  const auto& edges = meas.range_bin_edges;
  auto bin_name = [&](size_t r) {
    std::ostringstream b;
    b << int(edges[r]) << "-";
    if (r + 1 < edges.size()) b << int(edges[r + 1]);
    b << " m";
    return b.str();
  };
  for (const auto& [name, mc] : meas.classes) {
    const auto it = sim.classes.find(name);
    if (it == sim.classes.end() || mc.truth == 0) continue;
    const ClassStats& sc = it->second;
    o << "\n### " << name << " (" << mc.truth << " ground-truth boxes)\n\n";
    o << "| range | GT boxes | measured detection rate | simulated detection rate |\n|---|---|---|---|\n";
    for (size_t r = 0; r < mc.truth_by_range.size(); ++r) {
      if (mc.truth_by_range[r] == 0) continue;
      o << "| " << bin_name(r) << " | " << mc.truth_by_range[r] << " | " << std::setprecision(3)
        << double(mc.detected_by_range[r]) / mc.truth_by_range[r] << " | "
        << (sc.truth_by_range[r] ? double(sc.detected_by_range[r]) / sc.truth_by_range[r] : 0.0) << " |\n";
    }
    o << "| all | " << mc.truth << " | " << mc.recall() << " | " << sc.recall() << " |\n";
    o << "| > 50 m | " << mc.truth_beyond_50 << " | " << mc.recall_beyond_50() << " | " << sc.recall_beyond_50()
      << " |\n";
    static const char* occ_names[4] = {"occlusion 0 (visible)", "occlusion 1 (partly)", "occlusion 2 (largely)",
                                       "occlusion 3 (unknown)"};
    for (int k = 0; k < 4; ++k) {
      if (mc.truth_by_occlusion[k] == 0) continue;
      o << "| " << occ_names[k] << " | " << mc.truth_by_occlusion[k] << " | "
        << double(mc.detected_by_occlusion[k]) / mc.truth_by_occlusion[k] << " | "
        << (sc.truth_by_occlusion[k] ? double(sc.detected_by_occlusion[k]) / sc.truth_by_occlusion[k] : 0.0) << " |\n";
    }
    o << "\n| statistic | measured | simulated |\n|---|---|---|\n";
    o << "| mean miss-run length (frames) | " << mc.miss_burst_mean << " | " << sc.miss_burst_mean << " |\n";
    o << "| share of misses in runs >= 2 | " << mc.misses_in_bursts << " | " << sc.misses_in_bursts << " |\n";
    o << "| false positives per frame | " << double(mc.false_positives) / std::max(1L, meas.frames) << " | "
      << double(sc.false_positives) / std::max(1L, sim.frames) << " |\n";
    o << "| heading flip rate | " << mc.flip_rate << " | " << sc.flip_rate << " |\n";
    o << "| mean score of matches | " << mc.score_mean << " | " << sc.score_mean << " |\n";
    for (int p = 0; p < kNumKpiParams; ++p) {
      const ErrorStats &a = mc.errors[p], &b = sc.errors[p];
      o << "| " << to_string(static_cast<KpiParam>(p)) << " mean / std / lag-1 / excess kurtosis | "
        << std::setprecision(3) << a.mean << " / " << a.std << " / " << a.lag1 << " / " << std::setprecision(1)
        << a.excess_kurtosis << " | " << std::setprecision(3) << b.mean << " / " << b.std << " / " << b.lag1 << " / "
        << std::setprecision(1) << b.excess_kurtosis << " |\n";
    }
  }
  return o.str();
}

}  // namespace lidarsim::sensor
