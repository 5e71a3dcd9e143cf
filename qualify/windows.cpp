#include "qualify/windows.h"

#include <algorithm>

namespace lidarsim::qualify {

std::vector<double> category_edges(int n) {
  std::vector<double> e;
  for (int k = 0; k + 1 < n; ++k) e.push_back(k + 0.5);
  return e;
}

std::vector<double> equal_count_edges(const std::vector<double>& x, int bins) {
  // fit_binned_mean's binning, through a table fitted on zeros.
  return fit_binned_mean(x, std::vector<double>(x.size(), 0.0), bins).edges;
}

BinnedTable fit_gain_table(const std::vector<double>& edges, const std::vector<double>& x,
                           const std::vector<double>& measured, const std::vector<double>& base, double shrink) {
  BinnedTable t;
  t.edges = edges;
  std::vector<double> xy(edges.size() + 1, 0.0), xx = xy;
  t.count.assign(xy.size(), 0);
  for (size_t i = 0; i < x.size(); ++i) {
    const int b = t.bin(x[i]);
    xy[b] += measured[i] * base[i];
    xx[b] += base[i] * base[i];
    ++t.count[b];
  }
  t.value.assign(xy.size(), 1.0);
  for (size_t b = 0; b < xy.size(); ++b) {
    if (t.count[b] == 0 || xx[b] <= 0) continue;
    const double prior = shrink * xx[b] / t.count[b];  // shrink pseudo-cells at gain 1
    t.value[b] = (xy[b] + prior) / (xx[b] + prior);
  }
  return t;
}

BinnedTable fit_window(const std::vector<double>& edges, const std::vector<double>& x, const std::vector<double>& r,
                       double shrink) {
  BinnedTable fine;
  fine.edges = edges;
  const size_t nb = edges.size() + 1;
  if (nb < 3) return {};
  std::vector<double> sum(nb, 0.0);
  std::vector<long> cnt(nb, 0);
  for (size_t i = 0; i < x.size(); ++i) {
    const int b = fine.bin(x[i]);
    sum[b] += r[i];
    ++cnt[b];
  }
  double total = 0;
  long n = 0;
  for (size_t b = 0; b < nb; ++b) total += sum[b], n += cnt[b];
  // Drop of the squared error from one mean to two (inside, outside): n_in n_out / n (m_in - m_out)^2.
  double best = -1;
  size_t ba = 0, bb = 0;
  for (size_t a = 0; a < nb; ++a) {
    double s_in = 0;
    long n_in = 0;
    for (size_t b = a; b < nb; ++b) {
      s_in += sum[b], n_in += cnt[b];
      const long n_out = n - n_in;
      if (n_in == 0 || n_out == 0) continue;
      const double d = s_in / n_in - (total - s_in) / n_out;
      const double gain = static_cast<double>(n_in) * n_out / n * d * d;
      if (gain > best) best = gain, ba = a, bb = b;
    }
  }
  if (best < 0) return {};
  BinnedTable w;
  // Bins: below [.., lo), inside [lo, hi), above [hi, ..); below and above share the outside level.
  const double lo = ba == 0 ? -1e300 : edges[ba - 1], hi = bb + 1 >= nb ? 1e300 : edges[bb];
  w.edges = {lo, hi};
  double s_in = 0;
  long n_in = 0;
  for (size_t b = ba; b <= bb; ++b) s_in += sum[b], n_in += cnt[b];
  const double v_in = s_in / (n_in + shrink), v_out = (total - s_in) / (n - n_in + shrink);
  w.value = {v_out, v_in, v_out};
  w.count = {n - n_in, n_in, 0};
  return w;
}

BinnedTable fit_window_gain(const BinnedTable& window, const std::vector<double>& x,
                            const std::vector<double>& measured, const std::vector<double>& base, double shrink) {
  BinnedTable g = fit_gain_table(window.edges, x, measured, base, shrink);
  if (g.value.size() != 3) return g;
  // One level outside (below and above pooled).
  double xy = 0, xx = 0;
  long n = 0;
  for (size_t i = 0; i < x.size(); ++i)
    if (g.bin(x[i]) != 1) xy += measured[i] * base[i], xx += base[i] * base[i], ++n;
  if (n > 0 && xx > 0) {
    const double prior = shrink * xx / n;
    g.value[0] = g.value[2] = (xy + prior) / (xx + prior);
  }
  return g;
}

}  // namespace lidarsim::qualify
