#include "qualify/range_noise/range_noise_fit.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <numeric>

#include "common/error.h"
#include "pgm/materials.h"

namespace lidarsim::qualify {

std::vector<int> planar_classes() {
  return {pgm::cls::road, pgm::cls::parking, pgm::cls::sidewalk, pgm::cls::other_ground, pgm::cls::building,
          pgm::cls::fence};
}

namespace {

double median_of(std::vector<double>& v) {
  if (v.empty()) return 0;
  const std::size_t m = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + m, v.end());
  return v[m];
}

// One neighbourhood's fit; false when it is rejected.
bool residual_at(const std::vector<pgm::Point>& points, const std::vector<std::size_t>& order, std::size_t k, int K,
                 const RangeFitOptions& o, double& residual) {
  const pgm::Point& c = points[order[k]];
  const double r0 = std::sqrt(double(c.x) * c.x + double(c.y) * c.y + double(c.z) * c.z);
  const double ux = c.x / r0, uy = c.y / r0, uz = c.z / r0;
  // e = z x u, normalised: horizontal, across the beam (the row's direction of travel).
  double ex = -uy, ey = ux;
  const double en = std::hypot(ex, ey);
  if (en < 1e-6) return false;  // a beam straight up or down
  ex /= en, ey /= en;
  double n = 0, sa = 0, saa = 0, sw = 0, saw = 0, sww = 0;
  for (int d = -K; d <= K; ++d) {
    if (d == 0) continue;
    const pgm::Point& p = points[order[k + d]];
    const double a = p.x * ex + p.y * ey, w = p.x * ux + p.y * uy + p.z * uz;
    n += 1, sa += a, saa += a * a, sw += w, saw += a * w, sww += w * w;
  }
  const double det = n * saa - sa * sa;
  if (!(det > 1e-12 * n * n)) return false;  // the neighbours do not span the row
  const double c1 = (n * saw - sa * sw) / det, c0 = (sw - c1 * sa) / n;
  const double h = saa / det;  // leverage of a = 0: [(X^T X)^-1]_00
  if (n > 2) {
    // Residual sum of squares of the neighbours about their line.
    const double ssr = sww - c0 * sw - c1 * saw;
    const double rms = std::sqrt(std::max(0.0, ssr) / (n - 2));
    if (rms > o.max_neighbour_rms) return false;
  }
  const double e = r0 - c0;
  if (std::abs(e) > o.max_abs_residual) return false;
  residual = e / std::sqrt(1 + h);
  return true;
}

}  // namespace

std::vector<RangeResidual> range_residuals(const std::vector<pgm::Point>& points, const std::vector<int>& rows,
                                           const std::vector<float>& incidence, const RangeFitOptions& o) {
  if (rows.size() != points.size()) throw Error("range noise fit: " + std::to_string(rows.size()) + " rows for " +
                                                std::to_string(points.size()) + " points");
  if (!incidence.empty() && incidence.size() != points.size())
    throw Error("range noise fit: " + std::to_string(incidence.size()) + " incidence values for " +
                std::to_string(points.size()) + " points");
  if (o.half_window < 1) throw Error("range noise fit: half_window must be >= 1");
  std::vector<char> wanted(pgm::cls::count, 0);
  for (int c : o.classes)
    if (c >= 0 && c < pgm::cls::count) wanted[c] = 1;
  int n_rows = 0;
  for (int r : rows) n_rows = std::max(n_rows, r + 1);
  std::vector<std::vector<std::size_t>> by_row(n_rows);
  std::vector<double> azimuth(points.size());
  for (std::size_t i = 0; i < points.size(); ++i) {
    if (rows[i] < 0) continue;
    by_row[rows[i]].push_back(i);
    azimuth[i] = std::atan2(points[i].y, points[i].x);
  }
  std::vector<RangeResidual> out;
  const int K = o.half_window;
  std::vector<double> steps;
  for (auto& order : by_row) {
    if (order.size() < static_cast<std::size_t>(2 * K + 1)) continue;
    std::stable_sort(order.begin(), order.end(), [&](std::size_t i, std::size_t j) { return azimuth[i] < azimuth[j]; });
    steps.clear();
    for (std::size_t k = 1; k < order.size(); ++k) steps.push_back(azimuth[order[k]] - azimuth[order[k - 1]]);
    const double max_step = o.gap_factor * median_of(steps);
    // ok[k]: the step from k-1 to k is short (the surface is sampled without a hole between them).
    std::vector<char> ok(order.size(), 0);
    for (std::size_t k = 1; k < order.size(); ++k) ok[k] = azimuth[order[k]] - azimuth[order[k - 1]] <= max_step;
    for (std::size_t k = K; k + K < order.size(); ++k) {
      const pgm::Point& c = points[order[k]];
      if (c.class_id < 0 || c.class_id >= pgm::cls::count || !wanted[c.class_id]) continue;
      bool usable = true;
      for (int d = -K; d <= K && usable; ++d) {
        usable = points[order[k + d]].class_id == c.class_id;
        if (d > -K) usable = usable && ok[k + d];
      }
      if (!usable) continue;
      const double r0 = std::sqrt(double(c.x) * c.x + double(c.y) * c.y + double(c.z) * c.z);
      if (r0 < o.min_range) continue;
      double e = 0;
      if (!residual_at(points, order, k, K, o, e)) continue;
      RangeResidual rr;
      rr.range = static_cast<float>(r0);
      rr.residual = static_cast<float>(e);
      rr.incidence = incidence.empty() ? std::numeric_limits<float>::quiet_NaN() : incidence[order[k]];
      rr.intensity = c.intensity;
      rr.class_id = c.class_id;
      rr.material = c.material_id;
      rr.row = rows[order[k]];
      const double az = azimuth[order[k]] * (180 / std::numbers::pi);
      rr.azimuth_deg = static_cast<float>(az < 0 ? az + 360 : az);
      out.push_back(rr);
    }
  }
  return out;
}

std::vector<RangeResidual> scan_range_residuals(const std::vector<pgm::Point>& points, const pgm::BeamLayout& layout,
                                                const RangeFitOptions& options, const std::string& source) {
  pgm::ProjectOptions po;
  po.extra_channels = {"incidence"};
  const auto p = pgm::project(points, layout, po, source);
  const float* inc = p.pgm.channel("incidence");
  std::vector<int> rows(points.size(), -1);
  std::vector<float> incidence(points.size(), std::numeric_limits<float>::quiet_NaN());
  for (std::size_t i = 0; i < points.size(); ++i) {
    const std::int64_t cell = p.point_cell[i];
    if (cell < 0) continue;
    rows[i] = static_cast<int>(cell / layout.columns);
    if (inc[cell] > 0) incidence[i] = inc[cell];  // 0: not estimated (no neighbour in a direction)
  }
  return range_residuals(points, rows, incidence, options);
}

double robust_sigma(std::vector<float> v) {
  if (v.empty()) return 0;
  const std::size_t m = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + m, v.end());
  const float med = v[m];
  for (auto& x : v) x = std::abs(x - med);
  std::nth_element(v.begin(), v.begin() + m, v.end());
  return 1.4826 * v[m];
}

std::vector<SpreadBin> spread_by(const std::vector<RangeResidual>& residuals,
                                 const std::function<double(const RangeResidual&)>& key,
                                 const std::vector<double>& edges, std::size_t min_count) {
  std::vector<SpreadBin> out;
  if (edges.size() < 2) return out;
  std::vector<std::vector<float>> bins(edges.size() - 1);
  std::vector<double> key_sum(bins.size(), 0);
  for (const auto& r : residuals) {
    const double k = key(r);
    if (!std::isfinite(k)) continue;
    const auto it = std::upper_bound(edges.begin(), edges.end(), k);
    if (it == edges.begin() || it == edges.end()) continue;
    bins[it - edges.begin() - 1].push_back(r.residual);
    key_sum[it - edges.begin() - 1] += k;
  }
  for (std::size_t b = 0; b < bins.size(); ++b) {
    auto& v = bins[b];
    if (v.size() < min_count) continue;
    SpreadBin s;
    s.lo = edges[b], s.hi = edges[b + 1], s.n = v.size();
    s.mean = key_sum[b] / v.size();
    s.sigma = robust_sigma(v);
    const std::size_t m = v.size() / 2;
    std::nth_element(v.begin(), v.begin() + m, v.end());
    s.median = v[m];
    std::size_t far = 0;
    for (float x : v) far += std::abs(x - s.median) > 3 * s.sigma;
    s.tail3 = static_cast<double>(far) / v.size();
    out.push_back(s);
  }
  return out;
}

std::vector<double> quantile_edges(const std::vector<RangeResidual>& residuals,
                                   const std::function<double(const RangeResidual&)>& key, int count) {
  std::vector<double> v;
  for (const auto& r : residuals)
    if (const double k = key(r); std::isfinite(k)) v.push_back(k);
  std::vector<double> edges;
  if (v.empty() || count < 1) return edges;
  std::sort(v.begin(), v.end());
  edges.push_back(v.front());
  for (int i = 1; i < count; ++i) {
    const double e = v[v.size() * i / count];
    if (e > edges.back()) edges.push_back(e);
  }
  edges.push_back(std::nextafter(v.back(), std::numeric_limits<double>::infinity()));
  return edges;
}

SigmaFit fit_sigma_of_range(const std::vector<SpreadBin>& bins) {
  SigmaFit f;
  if (bins.empty()) return f;
  // s2 = A + B r^2 with A = a^2, B = b^2; r the bin's mean range.
  auto solve = [&](const std::vector<double>& w, bool use_a, bool use_b, double& A, double& B) {
    double s00 = 0, s01 = 0, s11 = 0, t0 = 0, t1 = 0;
    for (std::size_t i = 0; i < bins.size(); ++i) {
      const double r = bins[i].mean, x = r * r, y = bins[i].sigma * bins[i].sigma;
      s00 += w[i], s01 += w[i] * x, s11 += w[i] * x * x, t0 += w[i] * y, t1 += w[i] * x * y;
    }
    A = B = 0;
    if (use_a && use_b) {
      const double det = s00 * s11 - s01 * s01;
      if (det > 0) A = (t0 * s11 - t1 * s01) / det, B = (s00 * t1 - s01 * t0) / det;
    } else if (use_a) {
      A = s00 > 0 ? t0 / s00 : 0;
    } else if (use_b) {
      B = s11 > 0 ? t1 / s11 : 0;
    }
  };
  std::vector<double> w(bins.size());
  for (std::size_t i = 0; i < bins.size(); ++i) w[i] = static_cast<double>(bins[i].n) / std::pow(bins[i].sigma, 4);
  double A = 0, B = 0;
  for (int iter = 0; iter < 5; ++iter) {
    solve(w, true, true, A, B);
    if (A < 0) solve(w, false, true, A, B);
    else if (B < 0) solve(w, true, false, A, B);
    // Reweight by the fitted variance (the sample variance's own spread grows with it).
    for (std::size_t i = 0; i < bins.size(); ++i) {
      const double r = bins[i].mean, s2 = std::max(1e-12, A + B * r * r);
      w[i] = static_cast<double>(bins[i].n) / (s2 * s2);
    }
  }
  f.a = std::sqrt(std::max(0.0, A));
  f.b = std::sqrt(std::max(0.0, B));
  return f;
}

}  // namespace lidarsim::qualify
