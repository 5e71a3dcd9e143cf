#include "qualify/report.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>

#include "common/image.h"

namespace lidarsim::qualify {

std::string fmt(double v, int precision) {
  if (!std::isfinite(v)) return "n/a";
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*f", precision, v);
  return buf;
}

nlohmann::json to_json(const Similarity& s) {
  nlohmann::json j = {{"n_simulated", s.n_a},
                      {"n_measured", s.n_b},
                      {"intersection", s.intersection},
                      {"interval95", {s.interval.lo, s.interval.hi}},
                      {"ks", s.ks},
                      {"wasserstein", s.wasserstein}};
  if (s.ceiling >= 0) j["ceiling"] = s.ceiling;
  return j;
}

std::string similarity_cell(const Similarity& s) {
  std::string c = fmt(s.intersection) + " [" + fmt(s.interval.lo, 2) + ", " + fmt(s.interval.hi, 2) + "]";
  return c;
}

std::string file_stem(std::string s) {
  for (char& c : s) c = std::isalnum(static_cast<unsigned char>(c)) ? std::tolower(c) : '_';
  return s;
}

namespace {

void fill_rect(Image& im, int x0, int y0, int x1, int y1, Rgb c) {
  for (int y = std::max(0, y0); y < std::min(im.height, y1); ++y)
    for (int x = std::max(0, x0); x < std::min(im.width, x1); ++x) im.at(x, y) = c;
}

}  // namespace

std::string write_histogram_png(const std::filesystem::path& path, const std::vector<double>& sim,
                                const std::vector<double>& real, int bins) {
  const SharedBins sb = shared_bins(sim, real, bins);
  const auto p = histogram(sim, sb), q = histogram(real, sb);
  const int bw = 10, h = 160, pad = 4, n = static_cast<int>(p.size());
  Image im(n * bw + 2 * pad, h + 2 * pad, {255, 255, 255});
  double top = 1e-12;
  for (int k = 0; k < n; ++k) top = std::max({top, p[k], q[k]});
  const Rgb blue{70, 110, 200}, orange{240, 150, 40}, both{90, 60, 60};
  for (int k = 0; k < n; ++k) {
    const int hs = static_cast<int>(std::round(p[k] / top * h)), hr = static_cast<int>(std::round(q[k] / top * h));
    const int x0 = pad + k * bw, x1 = x0 + bw - 1, base = pad + h;
    fill_rect(im, x0, base - std::max(hs, hr), x1, base, hs > hr ? orange : blue);
    fill_rect(im, x0, base - std::min(hs, hr), x1, base, both);
  }
  fill_rect(im, pad, pad + h, im.width - pad, pad + h + 1, {0, 0, 0});
  write_png(path, im);
  return "bins of width " + fmt((sb.hi - sb.lo) / sb.bins, 4) + " from " + fmt(sb.lo) + " to " + fmt(sb.hi) +
         " plus an overflow bin at each end; blue measured, orange simulated, dark both";
}

std::string write_residual_png(const std::filesystem::path& path, const BinnedTable& t, const std::vector<double>& x,
                               const std::vector<double>& r) {
  const int n = static_cast<int>(t.value.size());
  std::vector<double> sum(n, 0.0);
  std::vector<long> cnt(n, 0);
  for (size_t i = 0; i < x.size(); ++i) {
    const int b = t.bin(x[i]);
    sum[b] += r[i];
    ++cnt[b];
  }
  double top = 1e-12;
  for (int b = 0; b < n; ++b) {
    if (cnt[b]) top = std::max(top, std::abs(sum[b] / cnt[b]));
    top = std::max(top, std::abs(t.value[b]));
  }
  const int bw = 24, half = 80, pad = 4;
  Image im(n * bw + 2 * pad, 2 * half + 2 * pad, {255, 255, 255});
  const int zero = pad + half;
  for (int b = 0; b < n; ++b) {
    const int x0 = pad + b * bw + 2, x1 = x0 + bw - 4;
    if (cnt[b]) {
      const int v = static_cast<int>(std::round(sum[b] / cnt[b] / top * half));
      fill_rect(im, x0, std::min(zero, zero - v), x1, std::max(zero, zero - v) + 1, {150, 150, 150});
    }
    const int tv = zero - static_cast<int>(std::round(t.value[b] / top * half));
    fill_rect(im, x0, tv - 1, x1, tv + 2, {240, 150, 40});
  }
  fill_rect(im, pad, zero, im.width - pad, zero + 1, {0, 0, 0});
  write_png(path, im);
  std::string edges;
  for (double e : t.edges) edges += (edges.empty() ? "" : ", ") + fmt(e, 3);
  return "one bar per feature bin (cuts at " + edges + "); grey: mean held-out residual, orange: table from the fit " +
         "split; full height = " + fmt(top, 4);
}

}  // namespace lidarsim::qualify
