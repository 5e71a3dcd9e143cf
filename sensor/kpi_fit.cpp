#include "sensor/kpi_fit.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <numeric>
#include <tuple>

#include "common/angles.h"
#include "common/error.h"
#include "sensor/hungarian.h"

namespace lidarsim::sensor {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

double wrap(double a) {
  a = std::fmod(a + kPi, 2 * kPi);
  if (a < 0) a += 2 * kPi;
  return a - kPi;
}

int bin_of(const std::vector<double>& edges, double x) {
  const auto it = std::upper_bound(edges.begin(), edges.end(), x);
  return std::max(0, static_cast<int>(it - edges.begin()) - 1);
}

// One ground-truth object in one frame.
struct Rec {
  int cls = 0, seq = 0, track = 0, frame = 0;
  int rb = 0, vb = 0, occ = 0;
  double range = 0;
  bool detected = false, flipped = false;
  double score = 0;
  std::array<double, kNumKpiParams> e;
  Eigen::Vector2d bev_err = Eigen::Vector2d::Zero(), u = Eigen::Vector2d(1, 0);
};
struct Fp {
  int cls = 0;
  double range = 0, az = 0, z = 0, score = 0;
};
struct Collected {
  std::vector<Rec> recs;  // sorted by class, sequence, track, frame
  std::vector<Fp> fps;
  long frames = 0;
  std::vector<Eigen::Vector3d> size_sum;
  std::vector<long> size_n;
};

int class_index(const FitOptions& opt, ObjectClass c) {
  const std::string name = kpi_class_name(c);
  for (size_t i = 0; i < opt.classes.size(); ++i)
    if (opt.classes[i] == name) return static_cast<int>(i);
  return -1;
}

Collected collect(const std::vector<CalibrationSequence>& seqs, const FitOptions& opt) {
  Collected c;
  const int nc = static_cast<int>(opt.classes.size());
  c.size_sum.assign(nc, Eigen::Vector3d::Zero());
  c.size_n.assign(nc, 0);
  for (size_t s = 0; s < seqs.size(); ++s) {
    const CalibrationSequence& seq = seqs[s];
    for (size_t f = 0; f < seq.frames.size(); ++f) {
      const CalibrationFrame& fr = seq.frames[f];
      ++c.frames;
      const std::vector<int> match = match_truth_to_detections(fr.truth, fr.detections, opt.gate, opt.min_score);
      std::vector<char> used(fr.detections.size(), 0);
      for (size_t i = 0; i < fr.truth.size(); ++i) {
        const Object& g = fr.truth[i];
        const int ci = class_index(opt, g.cls);
        if (ci < 0) continue;
        Rec r;
        r.cls = ci;
        r.seq = static_cast<int>(s);
        r.track = g.id;
        r.frame = static_cast<int>(f);
        const Eigen::Vector2d bev = g.position.head<2>();
        r.range = bev.norm();
        r.u = r.range > 1e-6 ? Eigen::Vector2d(bev / r.range) : Eigen::Vector2d(1, 0);
        r.rb = bin_of(opt.range_bin_edges, r.range);
        r.vb = bin_of(opt.visibility_bin_edges, g.visible_fraction);
        r.occ = i < fr.occlusion.size() ? std::clamp(fr.occlusion[i], 0, 3) : 0;
        r.e.fill(kNaN);
        c.size_sum[ci] += g.size;
        ++c.size_n[ci];
        if (match[i] >= 0) {
          used[match[i]] = 1;
          const Object& d = fr.detections[match[i]];
          r.detected = true;
          r.score = d.score;
          const Eigen::Vector2d left(-r.u.y(), r.u.x());
          r.bev_err = (d.position - g.position).head<2>();
          r.e[int(KpiParam::PositionAlong)] = r.bev_err.dot(r.u);
          r.e[int(KpiParam::PositionAcross)] = r.bev_err.dot(left);
          r.e[int(KpiParam::PositionVertical)] = d.position.z() - g.position.z();
          r.e[int(KpiParam::Length)] = d.size.x() - g.size.x();
          r.e[int(KpiParam::Width)] = d.size.y() - g.size.y();
          r.e[int(KpiParam::Height)] = d.size.z() - g.size.z();
          double h = wrap(d.heading - g.heading);
          r.flipped = std::abs(h) > kPi / 2;
          if (r.flipped) h = wrap(h - kPi);
          r.e[int(KpiParam::Heading)] = h;
        }
        c.recs.push_back(r);
      }
      for (size_t j = 0; j < fr.detections.size(); ++j) {
        const Object& d = fr.detections[j];
        if (used[j] || d.score <= opt.min_score) continue;
        const int ci = class_index(opt, d.cls);
        if (ci < 0) continue;
        bool near_other = false;
        for (const Object& o : fr.others)
          if ((o.position - d.position).head<2>().norm() <= opt.gate) near_other = true;
        if (near_other) continue;
        c.fps.push_back({ci, d.position.head<2>().norm(), std::atan2(d.position.y(), d.position.x()), d.position.z(),
                         d.score});
      }
    }
  }
  std::sort(c.recs.begin(), c.recs.end(), [](const Rec& a, const Rec& b) {
    return std::tie(a.cls, a.seq, a.track, a.frame) < std::tie(b.cls, b.seq, b.track, b.frame);
  });
  // Velocity errors: change of the position error between consecutive matched frames.
  for (size_t i = 1; i < c.recs.size(); ++i) {
    Rec& r = c.recs[i];
    const Rec& p = c.recs[i - 1];
    if (p.cls != r.cls || p.seq != r.seq || p.track != r.track || p.frame + 1 != r.frame) continue;
    if (!p.detected || !r.detected) continue;
    const double dt = seqs[r.seq].frame_dt;
    const Eigen::Vector2d dv = (r.bev_err - p.bev_err) / dt;
    r.e[int(KpiParam::VelocityAlong)] = dv.dot(r.u);
    r.e[int(KpiParam::VelocityAcross)] = dv.dot(Eigen::Vector2d(-r.u.y(), r.u.x()));
  }
  return c;
}

bool consecutive(const Rec& p, const Rec& r) {
  return p.cls == r.cls && p.seq == r.seq && p.track == r.track && p.frame + 1 == r.frame;
}

// Pooled mean/std/kurtosis and lag-1 autocorrelation along tracks of value(rec) (NaN = none).
template <class F>
ErrorStats error_stats(const std::vector<Rec>& recs, size_t begin, size_t end, F value) {
  ErrorStats s;
  double sum = 0;
  for (size_t i = begin; i < end; ++i) {
    const double v = value(recs[i]);
    if (std::isnan(v)) continue;
    sum += v;
    ++s.n;
  }
  if (s.n < 2) return s;
  s.mean = sum / s.n;
  double m2 = 0, m4 = 0, cross = 0, a2 = 0, b2 = 0;
  for (size_t i = begin; i < end; ++i) {
    const double v = value(recs[i]);
    if (std::isnan(v)) continue;
    const double d = v - s.mean;
    m2 += d * d;
    m4 += d * d * d * d;
    if (i > begin && consecutive(recs[i - 1], recs[i])) {
      const double w = value(recs[i - 1]);
      if (!std::isnan(w)) {
        cross += d * (w - s.mean);
        a2 += d * d;
        b2 += (w - s.mean) * (w - s.mean);
      }
    }
  }
  m2 /= s.n;
  m4 /= s.n;
  s.std = std::sqrt(m2);
  s.excess_kurtosis = m2 > 0 ? m4 / (m2 * m2) - 3 : 0;
  s.lag1 = a2 > 0 && b2 > 0 ? cross / std::sqrt(a2 * b2) : 0;
  return s;
}

std::vector<double> quantiles(std::vector<double> v, int n) {
  if (v.size() < 2 || n < 2) return {};
  std::sort(v.begin(), v.end());
  std::vector<double> q(n);
  for (int i = 0; i < n; ++i) {
    const double x = double(i) / (n - 1) * (v.size() - 1);
    const size_t k = std::min(static_cast<size_t>(x), v.size() - 2);
    q[i] = v[k] + (x - k) * (v[k + 1] - v[k]);
  }
  return q;
}

// Innovation distribution with unit variance and the kurtosis of eps (already ~unit variance).
Innovation fit_innovation(std::vector<double> eps) {
  Innovation in;
  if (eps.size() < 50) return in;
  double m2 = 0, m4 = 0;
  for (double x : eps) m2 += x * x;
  m2 /= eps.size();
  const double sd = std::sqrt(m2);
  for (double& x : eps) x /= sd;
  for (double x : eps) m4 += x * x * x * x;
  const double K = m4 / eps.size();  // raw kurtosis (3 for Gaussian)
  if (K < 3.3) return in;
  std::vector<double> a(eps.size());
  for (size_t i = 0; i < eps.size(); ++i) a[i] = std::abs(eps[i]);
  std::nth_element(a.begin(), a.begin() + a.size() / 2, a.end());
  const double s1 = std::min(0.98, 1.4826 * a[a.size() / 2]);  // core sigma from the MAD
  const double s1sq = s1 * s1;
  // Two-scale mixture with core variance s1^2, total variance 1, raw kurtosis K.
  const double wide = (K / 3 - s1sq * s1sq) / (1 - s1sq) - s1sq;  // sigma_wide^2
  const double p = (1 - s1sq) / (wide - s1sq);
  if (wide > 1 && p > 0 && p < 0.5) {
    in.type = Innovation::Type::Mixture;
    in.outlier_probability = p;
    in.outlier_scale = std::sqrt(wide) / s1;
    return in;
  }
  in.type = Innovation::Type::StudentT;
  in.dof = std::clamp(4 + 6 / (K - 3), 4.2, 100.0);
  return in;
}

// The steps of fit_error, on one parameter p of recs[begin, end).
struct ErrorFit {
  const std::vector<Rec>& recs;
  size_t begin, end;
  int p;
  const FitOptions& opt;
  ErrorModel em;
  std::vector<double> offset;  // per record: its track's constant (sizes), else 0

  double val(size_t i) const { return recs[i].e[p]; }
  double resid(size_t i) const { return val(i) - em.mean[recs[i].rb] - offset[i - begin]; }
  double z_of(size_t i) const { return resid(i) / (em.sigma[recs[i].rb] * em.visibility_std_scale[recs[i].vb]); }

  // Range-bin means (the pooled mean where a bin has too few samples).
  void fit_means(double pooled_mean) {
    const int nr = static_cast<int>(opt.range_bin_edges.size());
    em.mean.assign(nr, pooled_mean);
    std::vector<double> sum(nr, 0);
    std::vector<long> n(nr, 0);
    for (size_t i = begin; i < end; ++i) {
      const double v = val(i);
      if (std::isnan(v)) continue;
      sum[recs[i].rb] += v;
      ++n[recs[i].rb];
    }
    for (int r = 0; r < nr; ++r)
      if (n[r] >= opt.min_samples) em.mean[r] = sum[r] / n[r];
  }

  // Per-track constant (sizes): offset of each track's mean from the bin means, weighted by track
  // length, so between + within variance adds up to the total (short tracks' noisy means would
  // otherwise inflate the per-track spread).
  void fit_track_offsets() {
    double wsum = 0, wmean = 0, wvar = 0;
    std::vector<std::pair<double, long>> offsets;
    for (size_t i = begin; i < end;) {
      size_t j = i;
      double s = 0;
      long k = 0;
      while (j < end && recs[j].seq == recs[i].seq && recs[j].track == recs[i].track) {
        if (!std::isnan(val(j))) s += val(j) - em.mean[recs[j].rb], ++k;
        ++j;
      }
      if (k >= 3) {
        for (size_t q = i; q < j; ++q) offset[q - begin] = s / k;
        offsets.push_back({s / k, k});
        wsum += k;
        wmean += s;
      }
      i = j;
    }
    if (offsets.size() >= 5) {
      wmean /= wsum;
      for (const auto& [o, k] : offsets) wvar += k * (o - wmean) * (o - wmean);
      em.track_std = std::sqrt(wvar / wsum);
    }
  }

  // Range-bin sigmas of the residual (the residual's overall std where a bin has too few).
  void fit_sigmas(double pooled_std) {
    const int nr = static_cast<int>(opt.range_bin_edges.size());
    std::vector<double> sum2(nr, 0);
    std::vector<long> n(nr, 0);
    double all2 = 0;
    long all_n = 0;
    for (size_t i = begin; i < end; ++i) {
      const double v = resid(i);
      if (std::isnan(v)) continue;
      sum2[recs[i].rb] += v * v;
      ++n[recs[i].rb];
      all2 += v * v;
      ++all_n;
    }
    const double all_std = all_n > 1 ? std::sqrt(all2 / all_n) : pooled_std;
    em.sigma.assign(nr, all_std);
    for (int r = 0; r < nr; ++r)
      if (n[r] >= opt.min_samples) em.sigma[r] = std::max(1e-4, std::sqrt(sum2[r] / n[r]));
  }

  // Visibility: scale of the range-standardized residual per visibility bin.
  void fit_visibility_scale() {
    const int nv = static_cast<int>(opt.visibility_bin_edges.size());
    em.visibility_std_scale.assign(nv, 1.0);
    std::vector<double> s2(nv, 0);
    std::vector<long> k(nv, 0);
    for (size_t i = begin; i < end; ++i) {
      const double v = resid(i);
      if (std::isnan(v)) continue;
      const double z = v / em.sigma[recs[i].rb];
      s2[recs[i].vb] += z * z;
      ++k[recs[i].vb];
    }
    for (int b = 0; b < nv; ++b)
      if (k[b] >= opt.min_samples) em.visibility_std_scale[b] = std::max(0.05, std::sqrt(s2[b] / k[b]));
  }

  // Lag-1 autocorrelation of z along tracks, then the innovations it implies.
  void fit_ar1_and_innovation() {
    double cross = 0, a2 = 0, b2 = 0;
    for (size_t i = begin + 1; i < end; ++i) {
      if (!consecutive(recs[i - 1], recs[i])) continue;
      const double a = z_of(i), b = z_of(i - 1);
      if (std::isnan(a) || std::isnan(b)) continue;
      cross += a * b;
      a2 += a * a;
      b2 += b * b;
    }
    em.ar1 = a2 > 0 && b2 > 0 ? std::clamp(cross / std::sqrt(a2 * b2), -0.9, 0.98) : 0.0;
    std::vector<double> eps;
    const double norm = std::sqrt(1 - em.ar1 * em.ar1);
    for (size_t i = begin + 1; i < end; ++i) {
      if (!consecutive(recs[i - 1], recs[i])) continue;
      const double a = z_of(i), b = z_of(i - 1);
      if (std::isnan(a) || std::isnan(b)) continue;
      eps.push_back((a - em.ar1 * b) / norm);
    }
    em.innovation = fit_innovation(std::move(eps));
  }
};

// Fits one parameter of one class from recs[begin, end).
ErrorModel fit_error(const std::vector<Rec>& recs, size_t begin, size_t end, int p, const FitOptions& opt,
                     bool per_track_constant) {
  ErrorFit fit{recs, begin, end, p, opt, ErrorModel{}, std::vector<double>(end - begin, 0.0)};
  const ErrorStats pooled = error_stats(recs, begin, end, [&](const Rec& r) { return r.e[p]; });
  const double pooled_std = pooled.n > 1 && pooled.std > 0 ? pooled.std : 1e-3;
  fit.fit_means(pooled.mean);
  if (per_track_constant) fit.fit_track_offsets();
  fit.fit_sigmas(pooled_std);
  fit.fit_visibility_scale();
  fit.fit_ar1_and_innovation();
  return fit.em;
}

// Mean length of runs of `flag` over consecutive frames of a track, and the share of flagged
// frames in runs of length >= 2.
template <class F>
std::pair<double, double> burst_stats(const std::vector<Rec>& recs, size_t begin, size_t end, F flag) {
  long runs = 0, frames = 0, in_long = 0, cur = 0;
  auto close = [&] {
    if (cur > 0) {
      ++runs;
      frames += cur;
      if (cur >= 2) in_long += cur;
    }
    cur = 0;
  };
  for (size_t i = begin; i < end; ++i) {
    if (i > begin && !consecutive(recs[i - 1], recs[i])) close();
    if (flag(recs[i])) ++cur;
    else close();
  }
  close();
  return {runs ? double(frames) / runs : 1.0, frames ? double(in_long) / frames : 0.0};
}

std::pair<size_t, size_t> class_range(const std::vector<Rec>& recs, int ci) {
  const auto lo = std::lower_bound(recs.begin(), recs.end(), ci, [](const Rec& r, int c) { return r.cls < c; });
  const auto hi = std::upper_bound(recs.begin(), recs.end(), ci, [](int c, const Rec& r) { return c < r.cls; });
  return {static_cast<size_t>(lo - recs.begin()), static_cast<size_t>(hi - recs.begin())};
}


// One range row's detection rates: cell v's is (d_v + k m) / (n_v + k), k = kDetectionPriorObjects,
// with the prior m chosen so the row's expected detections equal its measured ones (the plain row
// rate as prior raised the rare low-rate cells and with them the re-simulated recall: Cyclist 0.944
// measured, 0.964 re-simulated). A row of fewer than k objects takes `fallback` as its prior.
std::vector<double> shrunk_detection_rates(const std::vector<long>& n, const std::vector<long>& d, double fallback) {
  const double k = kDetectionPriorObjects;
  double trials = 0, hits = 0, own = 0, weight = 0;
  for (size_t v = 0; v < n.size(); ++v) {
    trials += n[v], hits += d[v];
    own += n[v] * d[v] / (n[v] + k), weight += n[v] * k / (n[v] + k);
  }
  const double m = trials >= k && weight > 0 ? std::clamp((hits - own) / weight, 0.0, 1.0) : fallback;
  std::vector<double> p(n.size());
  for (size_t v = 0; v < n.size(); ++v) p[v] = (d[v] + k * m) / (n[v] + k);
  return p;
}

}  // namespace

std::vector<int> match_truth_to_detections(const std::vector<Object>& truth, const std::vector<Object>& dets,
                                           double gate, double min_score) {
  std::vector<int> out(truth.size(), -1);
  if (truth.empty() || dets.empty()) return out;
  const double big = gate * 1000 + 1e6;
  Eigen::MatrixXd cost(truth.size(), dets.size());
  for (size_t i = 0; i < truth.size(); ++i)
    for (size_t j = 0; j < dets.size(); ++j) {
      const double d = (truth[i].position - dets[j].position).head<2>().norm();
      const bool ok = dets[j].cls == truth[i].cls && dets[j].score > min_score && d <= gate;
      cost(i, j) = ok ? d : big;
    }
  HungarianSolver solver;
  const auto& a = solver.solve(cost);
  for (size_t i = 0; i < truth.size(); ++i)
    if (a[i] >= 0 && cost(i, a[i]) <= gate) out[i] = a[i];
  return out;
}

CalibrationStats measure_calibration_stats(const std::vector<CalibrationSequence>& seqs, const FitOptions& opt) {
  const Collected c = collect(seqs, opt);
  CalibrationStats st;
  st.range_bin_edges = opt.range_bin_edges;
  st.frames = c.frames;
  const int nr = static_cast<int>(opt.range_bin_edges.size());
  for (int ci = 0; ci < static_cast<int>(opt.classes.size()); ++ci) {
    ClassStats cs;
    cs.truth_by_range.assign(nr, 0);
    cs.detected_by_range.assign(nr, 0);
    const auto [b, e] = class_range(c.recs, ci);
    long flips = 0, matched = 0;
    double score = 0;
    for (size_t i = b; i < e; ++i) {
      const Rec& r = c.recs[i];
      ++cs.truth;
      ++cs.truth_by_range[r.rb];
      ++cs.truth_by_occlusion[r.occ];
      if (r.range > 50) ++cs.truth_beyond_50;
      if (!r.detected) continue;
      ++cs.detected;
      ++cs.detected_by_range[r.rb];
      ++cs.detected_by_occlusion[r.occ];
      if (r.range > 50) ++cs.detected_beyond_50;
      ++matched;
      flips += r.flipped;
      score += r.score;
    }
    cs.flip_rate = matched ? double(flips) / matched : 0;
    cs.score_mean = matched ? score / matched : 0;
    std::tie(cs.miss_burst_mean, cs.misses_in_bursts) = burst_stats(c.recs, b, e, [](const Rec& r) { return !r.detected; });
    for (const Fp& f : c.fps) cs.false_positives += f.cls == ci;
    for (int p = 0; p < kNumKpiParams; ++p) {
      cs.errors[p] = error_stats(c.recs, b, e, [p](const Rec& r) { return r.e[p]; });
      for (size_t i = b; i < e; ++i)
        if (!std::isnan(c.recs[i].e[p])) cs.samples[p].push_back(c.recs[i].e[p]);
    }
    st.classes[opt.classes[ci]] = cs;
  }
  return st;
}

ErrorModel fit_error_model(std::vector<ErrorSample> samples, const FitOptions& opt, bool per_track_constant) {
  const int nr = static_cast<int>(opt.range_bin_edges.size()), nv = static_cast<int>(opt.visibility_bin_edges.size());
  std::sort(samples.begin(), samples.end(), [](const ErrorSample& a, const ErrorSample& b) {
    return std::tie(a.seq, a.track, a.frame) < std::tie(b.seq, b.track, b.frame);
  });
  std::vector<Rec> recs(samples.size());
  for (size_t i = 0; i < samples.size(); ++i) {
    const ErrorSample& s = samples[i];
    if (s.range_bin < 0 || s.range_bin >= nr || s.visibility_bin < 0 || s.visibility_bin >= nv)
      throw Error("fit_error_model: sample " + std::to_string(i) + " has range bin " + std::to_string(s.range_bin) +
                  " / visibility bin " + std::to_string(s.visibility_bin) + ", outside the " + std::to_string(nr) +
                  " x " + std::to_string(nv) + " bins of the fit options");
    Rec& r = recs[i];
    r.seq = s.seq, r.track = s.track, r.frame = s.frame, r.rb = s.range_bin, r.vb = s.visibility_bin;
    r.detected = true;
    r.e.fill(std::numeric_limits<double>::quiet_NaN());
    r.e[0] = s.value;
  }
  return fit_error(recs, 0, recs.size(), 0, opt, per_track_constant);
}

KpiModel fit_kpi_model(const std::vector<CalibrationSequence>& seqs, const FitOptions& opt) {
  const Collected c = collect(seqs, opt);
  if (c.frames == 0) throw Error("kpi calibration: no frames to fit");
  KpiModel m;
  m.range_bin_edges = opt.range_bin_edges;
  m.visibility_bin_edges = opt.visibility_bin_edges;
  const int nr = m.range_bins(), nv = m.visibility_bins();
  for (int ci = 0; ci < static_cast<int>(opt.classes.size()); ++ci) {
    const auto [b, e] = class_range(c.recs, ci);
    long matched = 0;
    for (size_t i = b; i < e; ++i) matched += c.recs[i].detected;
    if (matched < opt.min_samples) continue;  // too little data: the class stays unmodelled
    ClassModel cm;
    for (int p = 0; p < kNumKpiParams; ++p) {
      const bool size = p == int(KpiParam::Length) || p == int(KpiParam::Width) || p == int(KpiParam::Height);
      cm.errors[p] = fit_error(c.recs, b, e, p, opt, size);
    }
    // Detection probability by range x visibility, each cell shrunk toward a prior for its range row
    // (kDetectionPriorObjects). Raw rates of cells with 15-30 objects were often exactly 0 or 1: a
    // miss (or a detection) there was then impossible, and such cells held half the held-out
    // detection deviance of a fold.
    std::vector<std::vector<long>> n(nr, std::vector<long>(nv, 0)), d = n;
    for (size_t i = b; i < e; ++i) {
      ++n[c.recs[i].rb][c.recs[i].vb];
      d[c.recs[i].rb][c.recs[i].vb] += c.recs[i].detected;
    }
    const double overall = double(matched) / std::max<size_t>(1, e - b);
    cm.detection_probability.assign(nr, std::vector<double>(nv, overall));
    for (int r = 0; r < nr; ++r)
      cm.detection_probability[r] = shrunk_detection_rates(n[r], d[r], overall);
    cm.miss_burst_mean = std::max(1.0, burst_stats(c.recs, b, e, [](const Rec& r) { return !r.detected; }).first);
    long flips = 0;
    std::vector<double> scores;
    for (size_t i = b; i < e; ++i)
      if (c.recs[i].detected) {
        flips += c.recs[i].flipped;
        scores.push_back(c.recs[i].score);
      }
    cm.heading_flip_probability = std::min(0.99, double(flips) / matched);
    cm.flip_burst_mean =
        std::max(1.0, burst_stats(c.recs, b, e, [](const Rec& r) { return r.detected && r.flipped; }).first);
    cm.score_quantiles = quantiles(scores, opt.quantiles);
    std::vector<double> fr, fa, fs;
    double fz = 0;
    for (const Fp& f : c.fps)
      if (f.cls == ci) fr.push_back(f.range), fa.push_back(f.az), fs.push_back(f.score), fz += f.z;
    cm.false_positive_rate = fr.size() >= 2 ? double(fr.size()) / c.frames : 0.0;
    if (cm.false_positive_rate > 0) {
      cm.fp_range_quantiles = quantiles(fr, opt.quantiles);
      cm.fp_azimuth_quantiles = quantiles(fa, opt.quantiles);
      cm.fp_score_quantiles = quantiles(fs, opt.quantiles);
      cm.fp_z = fz / fr.size();
    }
    if (c.size_n[ci] > 0) cm.mean_size = c.size_sum[ci] / double(c.size_n[ci]);
    m.classes[opt.classes[ci]] = std::move(cm);
  }
  if (m.classes.empty()) throw Error("kpi calibration: no class had enough matched detections to fit");
  m.validate("fitted model");
  return m;
}

KpiModel gaussian_iid_model(const std::vector<CalibrationSequence>& seqs, const FitOptions& opt) {
  FitOptions one = opt;
  one.range_bin_edges = {0};
  one.visibility_bin_edges = {0};
  KpiModel m = fit_kpi_model(seqs, one);
  for (auto& [name, c] : m.classes) {
    for (auto& e : c.errors) {
      e.sigma[0] = std::sqrt(e.sigma[0] * e.sigma[0] + e.track_std * e.track_std);
      e.track_std = 0;
      e.ar1 = 0;
      e.innovation = Innovation{};
    }
    c.miss_burst_mean = 1;  // close to independent misses (a run of 1 on average)
    c.heading_flip_probability = 0;
  }
  m.controller.enabled = false;
  m.source = "Gaussian iid baseline";
  return m;
}

}  // namespace lidarsim::sensor
