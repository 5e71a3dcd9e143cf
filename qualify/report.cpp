#include "qualify/report.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>

#include "common/image.h"
#include "common/plot.h"

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


std::string feature_axis_label(const std::string& feature) {
  // Units of both loops' vocabularies (qualify/objects/objects.h, qualify/intensity/intensity.h).
  static const std::map<std::string, std::string> unit = {
      {"range", "m"},
      {"azimuth", "rad"},
      {"radial_velocity", "m/s"},
      {"speed", "m/s"},
      {"longitudinal_velocity", "m/s"},
      {"lateral_velocity", "m/s"},
      {"acceleration", "m/s^2"},
      {"heading_to_line_of_sight", "rad"},
      {"occlusion", "KITTI level 0-3"},
      {"truncation", "share outside the view"},
      {"class", "id"},
      {"size", "box length, m"},
      {"box_width", "box width, m"},
      {"box_height", "box height, m"},
      {"track_age", "frames"},
      {"incidence_angle", "rad"},
      {"elevation", "rad"},
      {"height", "m above the sensor"},
      {"material", "id"},
      {"depth_discontinuity", "1 at an occlusion edge"}};
  const auto it = unit.find(feature);
  return it == unit.end() ? feature : feature + " (" + it->second + ")";
}

std::string write_histogram_png(const std::filesystem::path& path, const std::vector<double>& sim,
                                const std::vector<double>& real, const PlotLabels& labels, double intersection,
                                int bins) {
  const SharedBins sb = shared_bins(sim, real, bins);
  const auto p = histogram(sim, sb), q = histogram(real, sb);
  const int n = sb.bins;
  const double w = (sb.hi - sb.lo) / n;
  double top = 0;
  for (size_t k = 0; k < p.size(); ++k) top = std::max({top, p[k], q[k]});

  // Overflow bins sit in grey bands outside [lo, hi], one bin width away from it.
  const double under = sb.lo - 2 * w, over = sb.hi + 2 * w;
  ChartSpec spec;
  spec.title = labels.title.empty() ? labels.simulated + " vs measured" : labels.title;
  spec.x_label = labels.x_label;
  spec.y_label = labels.y_label.empty() ? "share of samples" : labels.y_label;
  spec.x_lo = sb.lo - 3 * w, spec.x_hi = sb.hi + 3 * w;
  spec.y_lo = 0, spec.y_hi = std::max(top, 1e-9) * 1.3;  // headroom for the legend
  // The overflow labels come first: they win over a range tick whose label would touch them.
  spec.x_ticks = {{under, "<"}, {over, ">"}};
  const auto values = nice_ticks(sb.lo, sb.hi, 8);
  const auto text = tick_labels(values);
  for (size_t i = 0; i < values.size(); ++i) spec.x_ticks.push_back({values[i], text[i]});
  Chart chart(spec);

  chart.band(spec.x_lo, sb.lo - w, kOverflow);
  chart.band(sb.hi + w, spec.x_hi, kOverflow);
  std::vector<double> edges(n + 1);
  for (int k = 0; k <= n; ++k) edges[k] = sb.lo + k * w;
  for (int k = 0; k < n; ++k) chart.bar(edges[k], edges[k + 1], 0, q[k + 1], kMeasured);
  chart.bar(under - w / 2, under + w / 2, 0, q[0], kMeasured);
  chart.bar(over - w / 2, over + w / 2, 0, q[n + 1], kMeasured);
  const int thick = 3;
  chart.step(edges, std::vector<double>(p.begin() + 1, p.end() - 1), kSimulated, thick);
  chart.step({under - w / 2, under + w / 2}, {p[0]}, kSimulated, thick);
  chart.step({over - w / 2, over + w / 2}, {p[n + 1]}, kSimulated, thick);

  std::vector<LegendEntry> legend = {{"measured (n = " + std::to_string(real.size()) + ")", kMeasured, Mark::box},
                                     {labels.simulated + " (n = " + std::to_string(sim.size()) + ")", kSimulated,
                                      Mark::line}};
  if (intersection >= 0) legend.push_back({"intersection " + fmt(intersection), {}, Mark::none});
  chart.legend(legend);
  write_png(path, chart.image());
  return "Blue bars: measured share of samples per bin; orange outline: " + labels.simulated + ". " +
         std::to_string(n) + " bins of width " + fmt(w, 4) + " from " + fmt(sb.lo) + " to " + fmt(sb.hi) +
         ", plus an overflow bin at each end (grey bands, \"<\" and \">\").";
}

std::string write_interval_png(const std::filesystem::path& path, const std::vector<IntervalRow>& rows,
                               const PlotLabels& labels, const std::string& second_name) {
  const Rgb kBetter{40, 150, 60}, kWorse{200, 40, 40}, kUndecided{140, 140, 140};
  const int n = static_cast<int>(rows.size());
  double lo = 0, hi = 0;
  for (const auto& r : rows) {
    lo = std::min({lo, r.lo, r.value}), hi = std::max({hi, r.hi, r.value});
    if (r.has_second) lo = std::min({lo, r.lo2, r.value2}), hi = std::max({hi, r.hi2, r.value2});
  }
  if (!(hi > lo)) hi = lo + 1;
  ChartSpec spec;
  spec.title = labels.title;
  spec.x_label = labels.x_label;
  spec.y_label = labels.y_label;
  spec.width = 1120, spec.height = std::max(360, 140 + 34 * n);
  spec.x_lo = lo - 0.05 * (hi - lo), spec.x_hi = hi + 1.1 * (hi - lo);  // room for the legend
  spec.y_lo = -0.8, spec.y_hi = n - 0.2;
  // Row i at y = n - 1 - i: the first row on top, as in the table.
  for (int i = 0; i < n; ++i) spec.y_ticks.push_back({static_cast<double>(n - 1 - i), rows[i].label});
  Chart chart(spec);
  chart.line(0, spec.y_lo, 0, spec.y_hi, {0, 0, 0}, 2);
  auto colour = [&](double a, double b) { return a > 0 ? kBetter : b < 0 ? kWorse : kUndecided; };
  for (int i = 0; i < n; ++i) {
    const IntervalRow& r = rows[i];
    const double y = n - 1 - i;
    chart.line(r.lo, y, r.hi, y, colour(r.lo, r.hi), 4);
    chart.marker(r.value, y, colour(r.lo, r.hi), 6);
    if (r.has_second) {
      const double y2 = y - 0.3;
      chart.line(r.lo2, y2, r.hi2, y2, colour(r.lo2, r.hi2), 2);
      chart.marker(r.value2, y2, colour(r.lo2, r.hi2), 4);
      chart.marker(r.value2, y2, {255, 255, 255}, 2);
    }
  }
  std::vector<LegendEntry> legend{{"interval above 0", kBetter, Mark::line},
                                  {"below 0", kWorse, Mark::line},
                                  {"spans 0", kUndecided, Mark::line}};
  if (!second_name.empty()) legend.push_back({"thin, open dot: " + second_name, kUndecided, Mark::none});
  chart.legend(legend);
  write_png(path, chart.image());
  return "One row per item: the dot is the difference, the bar its 95% interval, the black line 0; green where the "
         "interval lies above 0, red below, grey across it" +
         (second_name.empty() ? std::string(".") : "; the thin bar with an open dot below each row: " + second_name + ".");
}

std::string write_residual_png(const std::filesystem::path& path, const BinnedTable& t, const std::vector<double>& x,
                               const std::vector<double>& r, const PlotLabels& labels) {
  const int n = static_cast<int>(t.value.size());
  std::vector<double> sum(n, 0.0);
  std::vector<long> cnt(n, 0);
  double x_min = std::numeric_limits<double>::infinity(), x_max = -x_min;
  for (size_t i = 0; i < x.size() && i < r.size(); ++i) {
    const int b = t.bin(x[i]);
    sum[b] += r[i];
    ++cnt[b];
    x_min = std::min(x_min, x[i]), x_max = std::max(x_max, x[i]);
  }
  double lo = 0, hi = 0;
  for (int b = 0; b < n; ++b) {
    if (cnt[b]) lo = std::min(lo, sum[b] / cnt[b]), hi = std::max(hi, sum[b] / cnt[b]);
    lo = std::min(lo, t.value[b]), hi = std::max(hi, t.value[b]);
  }
  if (!(hi > lo)) hi = lo + 1;  // all zero: any scale shows that

  // Bin k takes the slot [k, k + 1): the bins hold equal counts, not equal widths, so a true x
  // scale would squeeze the dense bins. Ticks: the edges, and the data's ends outside them.
  ChartSpec spec;
  spec.title = labels.title;
  spec.x_label = labels.x_label + (labels.x_label.empty() ? "" : "; ") + "bins of equal count, ticks at bin edges";
  spec.y_label = labels.y_label.empty() ? "mean residual" : labels.y_label;
  spec.x_lo = 0, spec.x_hi = n;
  spec.y_lo = lo, spec.y_hi = hi + 0.4 * (hi - lo);  // headroom for the legend
  std::vector<double> at, values;
  if (x_min < (t.edges.empty() ? x_max : t.edges.front())) at.push_back(0), values.push_back(x_min);
  for (size_t k = 0; k < t.edges.size(); ++k) at.push_back(k + 1.0), values.push_back(t.edges[k]);
  if (x_max >= (t.edges.empty() ? x_min : t.edges.back()) && x_max > x_min) at.push_back(n), values.push_back(x_max);
  const auto text = tick_labels(values, 0.25);  // bin edges are uneven: round them
  for (size_t i = 0; i < at.size(); ++i) spec.x_ticks.push_back({at[i], text[i]});
  Chart chart(spec);

  for (int b = 0; b < n; ++b) {
    if (cnt[b]) chart.bar(b + 0.2, b + 0.8, 0, sum[b] / cnt[b], kResidual);
    chart.line(b + 0.08, t.value[b], b + 0.92, t.value[b], kSimulated, 4);
  }
  chart.hline(0, {0, 0, 0});
  chart.legend({{"mean held-out residual", kResidual, Mark::box},
                {"table fitted on the fit split", kSimulated, Mark::line}});
  write_png(path, chart.image());
  std::string edges;
  for (double e : t.edges) edges += (edges.empty() ? "" : ", ") + fmt(e, 3);
  return "One slot per equal-count bin of the feature (cuts at " + edges +
         "); grey bars: mean held-out residual, orange marks: the table fitted on the fit split, black: zero.";
}

std::string candidates_markdown(const nlohmann::json& candidates) {
  std::vector<const nlohmann::json*> rows;
  for (const auto& c : candidates) rows.push_back(&c);
  std::stable_sort(rows.begin(), rows.end(), [](const nlohmann::json* a, const nlohmann::json* b) {
    return (*a)["score"].get<double>() > (*b)["score"].get<double>();
  });
  std::string md = "\n## Every candidate tested (" + std::to_string(rows.size()) +
                   ")\n\n| target | feature | kind | form (fold 1) | effect size | held-out score [95%] | error | "
                   "before | after | decision and why |\n|---|---|---|---|---|---|---|---|---|---|\n";
  for (const nlohmann::json* c : rows) {
    const auto& r = *c;
    md += "| " + r["target"].get<std::string>() + " | " + r["feature"].get<std::string>() + " | " +
          r["kind"].get<std::string>() + " | " + r["form_fold1"].get<std::string>() + " | " +
          fmt(r["effect_size"].get<double>()) + " | " + fmt(r["score"].get<double>()) + " [" +
          fmt(r["interval95"][0].get<double>()) + ", " + fmt(r["interval95"][1].get<double>()) + "] | " +
          r["error_metric"].get<std::string>() + " | " + fmt(r["error_before"].get<double>(), 4) + " | " +
          fmt(r["error_after"].get<double>(), 4) + " | " + r.value("reason", r["decision"].get<std::string>()) + " |\n";
  }
  return md;
}

}  // namespace lidarsim::qualify
