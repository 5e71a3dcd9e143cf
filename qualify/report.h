#pragma once
// Report helpers: number formatting, JSON of a Similarity, and two PNG plots (common/plot.h) that
// read on their own: title, labelled axes, legend. Each also returns a caption for the Markdown.
#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "common/image.h"
#include "qualify/residual.h"
#include "qualify/similarity.h"

namespace lidarsim::qualify {

// The report plots' colours: measured data, a model, shaded overflow, residuals.
inline constexpr Rgb kMeasured{110, 160, 220}, kSimulated{225, 110, 0}, kOverflow{238, 238, 238},
    kResidual{150, 150, 150};

std::string fmt(double v, int precision = 3);
nlohmann::json to_json(const Similarity& s);
// "0.912 [0.90, 0.93] (ceiling 0.95)"
std::string similarity_cell(const Similarity& s);

// What a plot is about; the axes' units belong in the labels ("position_along error (m)").
struct PlotLabels {
  std::string title, x_label, y_label;
  std::string simulated = "simulated";  // legend name of the first sample (e.g. "predicted")
};

// Histograms on shared bins: measured as filled blue bars, simulated as an orange outline on top,
// x over [lo, hi] with the two overflow bins in grey bands at the ends ("<", ">"), y = share of
// samples (the default y label). intersection >= 0 is shown in the legend. Returns the caption.
std::string write_histogram_png(const std::filesystem::path& path, const std::vector<double>& simulated,
                                const std::vector<double>& measured, const PlotLabels& labels,
                                double intersection = -1, int bins = kDefaultBins);
// Residual vs feature, one slot per (equal-count) bin of the table with the bin edges as x ticks:
// mean held-out residual (grey bars), the table fitted on the fit split (orange marks), zero line.
// Returns the caption.
std::string write_residual_png(const std::filesystem::path& path, const BinnedTable& table,
                               const std::vector<double>& x, const std::vector<double>& r, const PlotLabels& labels);

// Differences with their intervals, one row per item (a forest plot), for "is A better than B on
// each KPI": a dot at the difference, a bar over its interval, a line at 0; a row whose interval
// lies above 0 is green, below 0 red, across 0 grey. Up to two series per row (e.g. a model and
// its nested variant), the second drawn as an open marker just below the first. Returns the caption.
struct IntervalRow {
  std::string label;
  double value = 0, lo = 0, hi = 0;
  bool has_second = false;
  double value2 = 0, lo2 = 0, hi2 = 0;
};
std::string write_interval_png(const std::filesystem::path& path, const std::vector<IntervalRow>& rows,
                               const PlotLabels& labels, const std::string& second_name = "");

// A loop feature as an axis label, with its unit where it has one: "size (box length, m)".
std::string feature_axis_label(const std::string& feature);

// Markdown/JSON file names: safe stems ("Car position_along" -> "car_position_along").
std::string file_stem(std::string s);

// The object loop's "candidates" (every feature x target x form tested) as a Markdown section:
// kind, effect size, held-out score and interval, error before -> after and the decision with its
// reason, sorted by score, so a reader sees what was ruled out as well as what was added.
std::string candidates_markdown(const nlohmann::json& candidates);

}  // namespace lidarsim::qualify
