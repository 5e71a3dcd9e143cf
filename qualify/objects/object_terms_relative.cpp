// The relative line (object_terms.h backfit_relative_line): a size error that is a share of the
// object's own size, the share a straight line in a feature.
#include <algorithm>
#include <cmath>
#include <map>

#include "qualify/objects/object_terms.h"

namespace lidarsim::qualify::obj {

BinnedTable fit_relative_line_table(const std::vector<double>& x, const std::vector<double>& y,
                                    const std::vector<double>& size) {
  const size_t n = x.size();
  double mx = 0, mz = 0, sw = 0;
  std::vector<double> sorted = x;
  std::sort(sorted.begin(), sorted.end());
  const double q1 = n ? sorted[n / 100] : 0.0, q99 = n ? sorted[n - 1 - n / 100] : 0.0;
  // Least squares of y ~ s (a + b x) is y / s on x with weights s^2; a record without a size
  // (s <= 0) carries no share.
  for (size_t i = 0; i < n; ++i) {
    if (!(size[i] > 0)) continue;
    const double w = size[i] * size[i];
    mx += w * std::clamp(x[i], q1, q99), mz += w * y[i] / size[i], sw += w;
  }
  BinnedTable t;
  if (!(sw > 0)) {
    t.value = {0.0};
    t.count = {static_cast<long>(n)};
    return t;
  }
  mx /= sw, mz /= sw;
  double sxz = 0, sxx = 0;
  for (size_t i = 0; i < n; ++i) {
    if (!(size[i] > 0)) continue;
    const double w = size[i] * size[i], dx = std::clamp(x[i], q1, q99) - mx;
    sxz += w * dx * (y[i] / size[i] - mz), sxx += w * dx * dx;
  }
  if (!(q99 - q1 > 0) || !(sxx > 0)) {
    t.value = {mz};
    t.count = {static_cast<long>(n)};
    return t;
  }
  const double b = sxz / sxx;
  return line_table(mz - b * mx, b, q1, q99, x);
}

ClassTables fit_class_relative_lines(const std::vector<double>& x, const std::vector<double>& y,
                                     const std::vector<double>& size, const std::vector<int>& cls) {
  ClassTables t;
  t.pooled = fit_relative_line_table(x, y, size);
  for (int c = 0; c < kObjectClassCount; ++c) {
    std::vector<double> xc, yc, sc;
    for (size_t i = 0; i < x.size(); ++i)
      if (cls[i] == c) xc.push_back(x[i]), yc.push_back(y[i]), sc.push_back(size[i]);
    if (xc.size() >= 200) t.per_class[c] = fit_relative_line_table(xc, yc, sc), t.own[c] = true;
  }
  return t;
}

Refit backfit_relative_line(const std::vector<double>& x, const std::vector<double>& r, const std::vector<double>& size,
                            const std::vector<int>& cls, const std::vector<int>& rb, int relative_feature) {
  Refit f;
  f.relative = relative_feature;
  std::vector<double> y(r.size());
  // As backfit: the term on what the (class, range bin) cells leave, then each cell (>= 20 samples)
  // its mean residual after the term; four passes.
  for (int pass = 0; pass < 4; ++pass) {
    for (size_t i = 0; i < r.size(); ++i) {
      const auto it = f.d.find({cls[i], rb[i]});
      y[i] = r[i] - (it == f.d.end() ? 0.0 : it->second);
    }
    f.table = fit_class_relative_lines(x, y, size, cls);
    std::map<std::pair<int, int>, std::pair<double, long>> acc;
    for (size_t i = 0; i < r.size(); ++i) {
      auto& a = acc[{cls[i], rb[i]}];
      a.first += r[i] - f.table(cls[i], x[i]) * size[i], ++a.second;
    }
    f.d.clear();
    for (const auto& [k, a] : acc)
      if (a.second >= 20) f.d[k] = a.first / a.second;
  }
  return f;
}

int own_dimension(int t) {
  const std::string& target = kObjectTargets[t];
  if (target == "length") return feature_index("size");
  if (target == "width") return feature_index("box_width");
  if (target == "height") return feature_index("box_height");
  return -1;
}

}  // namespace lidarsim::qualify::obj
