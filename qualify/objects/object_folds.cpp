#include "qualify/objects/object_folds.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <numbers>

#include "common/error.h"

namespace lidarsim::qualify::obj {

double wrap(double a) {
  constexpr double kPi = std::numbers::pi;
  a = std::fmod(a + kPi, 2 * kPi);
  if (a < 0) a += 2 * kPi;
  return a - kPi;
}

int class_index(sensor::ObjectClass c) {
  switch (c) {
    case sensor::ObjectClass::Car: return 0;
    case sensor::ObjectClass::Pedestrian: return 1;
    case sensor::ObjectClass::Cyclist: return 2;
    default: return -1;
  }
}

int feature_index(const std::string& name) {
  for (size_t i = 0; i < kObjectFeatures.size(); ++i)
    if (kObjectFeatures[i] == name) return static_cast<int>(i);
  throw Error("object feature \"" + name + "\" is not in the vocabulary");
}

// Unit of a residual target, for axis labels.
std::string target_unit(const std::string& target) {
  return target == "heading" ? "(rad)" : target == "detection" ? "(detected 0/1)" : "(m)";
}

double rms(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x * x;
  return v.empty() ? 0 : std::sqrt(s / v.size());
}

std::vector<double> Split::column(int f) const {
  std::vector<double> x(rec.size());
  for (size_t i = 0; i < x.size(); ++i) x[i] = rec[i]->feature[f];
  return x;
}
std::vector<int> Split::classes() const {
  std::vector<int> c(rec.size());
  for (size_t i = 0; i < c.size(); ++i) c[i] = rec[i]->cls;
  return c;
}
std::vector<int> Split::tracks() const {
  std::map<std::pair<int, int>, int> id;  // track ids are per sequence
  std::vector<int> t(rec.size());
  for (size_t i = 0; i < t.size(); ++i)
    t[i] = id.try_emplace({rec[i]->seq, rec[i]->track}, static_cast<int>(id.size())).first->second;
  return t;
}
std::vector<int> Split::cells(int t, int nvis) const {
  std::vector<int> c(rec.size());
  for (size_t i = 0; i < c.size(); ++i)
    c[i] = t == kDetectionTarget ? rec[i]->range_bin * nvis + rec[i]->visibility_bin : rec[i]->range_bin;
  return c;
}
std::vector<double> Split::clipped(const Winsor& w) const {
  std::vector<double> out(r.size());
  for (size_t i = 0; i < out.size(); ++i) out[i] = w(r[i]);
  return out;
}

double base_residual(const sensor::KpiModel& base, const ObjectRecord& r, int t) {
  const auto it = base.classes.find(kObjectClasses[r.cls]);
  if (it == base.classes.end()) return kNaN;
  const sensor::ClassModel& cm = it->second;
  if (t == kDetectionTarget) return r.value[t] - cm.detection_probability[r.range_bin][r.visibility_bin];
  if (!r.detected) return kNaN;
  return r.value[t] - cm.errors[int(kTargetParam[t])].mean[r.range_bin];
}

Split gather(const ObjectSet& s, const sensor::KpiModel& base, int t) {
  Split out;
  for (const auto& r : s.records) {
    const double v = base_residual(base, r, t);
    if (std::isnan(v)) continue;
    out.r.push_back(v);
    out.rec.push_back(&r);
  }
  return out;
}

// Built in place: the Splits point into the fold's own ObjectSets.
void make_fold(Fold& k, const TrackingData& data, std::vector<int> fit_idx, std::vector<int> held_idx,
               const sensor::FitOptions& opt) {
  k.fit_idx = std::move(fit_idx);
  k.held_idx = std::move(held_idx);
  std::vector<sensor::CalibrationSequence> seqs;
  for (int s : k.fit_idx) seqs.push_back(data.calib[s]);
  k.base = sensor::fit_kpi_model(seqs, opt);
  k.fit_set = collect_objects(data, k.fit_idx, nullptr, opt);
  if (k.pool_track_spread) k.track_spread_factor = pool_track_spread(k.base, k.fit_set);
  if (!k.held_idx.empty()) k.held_set = collect_objects(data, k.held_idx, nullptr, opt);
  for (int t = 0; t < kObjectTargetCount; ++t) {
    k.fit_r.push_back(gather(k.fit_set, k.base, t));
    k.held_r.push_back(gather(k.held_set, k.base, t));
    k.win.push_back(winsor_limits(k.fit_r[t].r));
  }
}

std::vector<std::array<double, 3>> pool_track_spread(sensor::KpiModel& m, const ObjectSet& fit) {
  PerClass<std::map<std::pair<int, int>, int>> frames;  // per class: detected frames per track
  for (const auto& r : fit.records)
    if (r.detected && r.cls >= 0 && r.cls < kObjectClassCount) ++frames[r.cls][{r.seq, r.track}];
  PerClass<int> tracks{};
  for (int c = 0; c < kObjectClassCount; ++c)
    for (const auto& [key, n] : frames[c]) tracks[c] += n >= 3;
  std::vector<std::array<double, 3>> applied(kObjectClassCount, {1.0, 1.0, 1.0});
  const sensor::KpiParam params[3] = {sensor::KpiParam::Length, sensor::KpiParam::Width, sensor::KpiParam::Height};
  for (int q = 0; q < 3; ++q) {
    PerClass<double> l{}, v{}, sw{};
    PerClass<bool> use{};
    int m_used = 0;
    for (int c = 0; c < kObjectClassCount; ++c) {
      const auto it = m.classes.find(kObjectClasses[c]);
      if (it == m.classes.end() || tracks[c] < 3) continue;
      const sensor::ErrorModel& em = it->second.errors[int(params[q])];
      double s2 = 0;
      for (double s : em.sigma) s2 += s * s;
      sw[c] = std::sqrt(s2 / std::max<size_t>(1, em.sigma.size()));
      if (em.track_std <= 0 || sw[c] <= 0) continue;
      l[c] = std::log(em.track_std / sw[c]), v[c] = 1.0 / (2.0 * (tracks[c] - 1)), use[c] = true, ++m_used;
    }
    if (m_used < 2) continue;
    double wsum = 0, mu = 0, mean_l = 0, mean_v = 0;
    for (int c = 0; c < kObjectClassCount; ++c)
      if (use[c]) wsum += 1 / v[c], mu += l[c] / v[c], mean_l += l[c], mean_v += v[c];
    mu /= wsum, mean_l /= m_used, mean_v /= m_used;
    double spread = 0;
    for (int c = 0; c < kObjectClassCount; ++c)
      if (use[c]) spread += (l[c] - mean_l) * (l[c] - mean_l);
    const double tau2 = std::max(0.0, spread / (m_used - 1) - mean_v);
    for (int c = 0; c < kObjectClassCount; ++c) {
      if (!use[c]) continue;
      const double pooled = mu + (tau2 / (tau2 + v[c])) * (l[c] - mu);
      sensor::ErrorModel& em = m.classes.find(kObjectClasses[c])->second.errors[int(params[q])];
      const double next = sw[c] * std::exp(pooled);
      applied[c][q] = next / em.track_std;
      em.track_std = next;
    }
  }
  return applied;
}

std::vector<std::string> names_of(const TrackingData& data, const std::vector<int>& idx) {
  std::vector<std::string> out;
  for (int s : idx) out.push_back(data.names[s]);
  return out;
}

bool fixed_to_sensor(const std::string& feature) {
  return std::find(kSensorFixedFeatures.begin(), kSensorFixedFeatures.end(), feature) != kSensorFixedFeatures.end();
}

TimeBlocks split_into_time_blocks(const TrackingData& data, int blocks, const sensor::FitOptions& opt) {
  if (blocks < 2) throw Error("time blocks: need at least 2 blocks per sequence, got " + std::to_string(blocks));
  auto modelled = [](const std::string& type) {
    return std::find(kObjectClasses.begin(), kObjectClasses.end(), type) != kObjectClasses.end();
  };
  TimeBlocks out;
  for (size_t s = 0; s < data.kitti.size(); ++s) {
    const data::KittiTrackingSequence& ks = data.kitti[s];
    const sensor::CalibrationSequence& cs = data.calib[s];
    // Each track's first and last frame; the tracks by middle frame, cut into runs of equal count.
    std::map<int, std::pair<int, int>> span;
    for (size_t f = 0; f < ks.frames.size(); ++f)
      for (const auto& o : ks.frames[f].truth)
        if (modelled(o.type)) span.try_emplace(o.object.id, int(f), int(f)).first->second.second = int(f);
    std::vector<std::pair<int, int>> order;  // (first + last, track)
    for (const auto& [id, fl] : span) order.push_back({fl.first + fl.second, id});
    std::sort(order.begin(), order.end());
    std::map<int, int> block_of;
    for (size_t i = 0; i < order.size(); ++i) block_of[order[i].second] = static_cast<int>(i * blocks / order.size());
    // The whole sequence's matching: each truth keeps its own detection.
    std::vector<std::vector<int>> match(cs.frames.size());
    for (size_t f = 0; f < cs.frames.size(); ++f)
      match[f] = sensor::match_truth_to_detections(cs.frames[f].truth, cs.frames[f].detections, opt.gate, opt.min_score);
    for (int b = 0; b < blocks; ++b) {
      data::KittiTrackingSequence kb;
      kb.name = ks.name;
      kb.calib = ks.calib;
      kb.frames.resize(ks.frames.size());
      for (size_t f = 0; f < ks.frames.size(); ++f) {
        const data::KittiTrackingFrame& in = ks.frames[f];
        data::KittiTrackingFrame& fr = kb.frames[f];
        fr.frame = in.frame;
        // owner[d]: the block of the truth detection d matched (-1: none).
        std::vector<int> owner(in.detections.size(), -1);
        size_t i = 0;  // index among the modelled truths (CalibrationFrame::truth)
        for (const auto& o : in.truth) {
          if (!modelled(o.type)) {
            fr.truth.push_back(o);
            continue;
          }
          const int ob = block_of.at(o.object.id);
          if (f < match.size() && i < match[f].size() && match[f][i] >= 0) owner[match[f][i]] = ob;
          if (ob == b) fr.truth.push_back(o);
          ++i;
        }
        for (size_t d = 0; d < in.detections.size(); ++d)
          if (owner[d] < 0 || owner[d] == b) fr.detections.push_back(in.detections[d]);
      }
      out.data.names.push_back(data.names[s] + " block " + std::to_string(b + 1) + "/" + std::to_string(blocks));
      out.data.calib.push_back(data::to_calibration_sequence(kb));
      out.data.calib.back().frame_dt = cs.frame_dt;
      out.data.calib.back().name = cs.name;
      out.data.kitti.push_back(std::move(kb));
      out.origin.push_back(static_cast<int>(s));
      out.block.push_back(b);
    }
  }
  return out;
}

std::array<std::vector<int>, 2> time_block_sides(const TimeBlocks& tb) {
  std::array<std::vector<int>, 2> sides;
  for (size_t i = 0; i < tb.block.size(); ++i) sides[tb.block[i] % 2].push_back(static_cast<int>(i));
  return sides;
}

}  // namespace lidarsim::qualify::obj
