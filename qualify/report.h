#pragma once
// Report helpers: number formatting, JSON of a Similarity, and two simple PNG plots drawn
// pixel by pixel (common/image.h has no text: the Markdown caption names axes and ranges).
#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "qualify/residual.h"
#include "qualify/similarity.h"

namespace lidarsim::qualify {

std::string fmt(double v, int precision = 3);
nlohmann::json to_json(const Similarity& s);
// "0.912 [0.90, 0.93] (ceiling 0.95)"
std::string similarity_cell(const Similarity& s);

// Overlaid histograms on shared bins: measured in blue, simulated in orange, overlap dark.
// Returns the caption text (bin range) for the Markdown.
std::string write_histogram_png(const std::filesystem::path& path, const std::vector<double>& simulated,
                                const std::vector<double>& measured, int bins = kDefaultBins);
// Residual vs feature: mean held-out residual per bin of the feature table (grey bars) and the
// table fitted on the fit split (orange ticks); zero line in black.
std::string write_residual_png(const std::filesystem::path& path, const BinnedTable& table,
                               const std::vector<double>& x, const std::vector<double>& r);

// Markdown/JSON file names: safe stems ("Car position_along" -> "car_position_along").
std::string file_stem(std::string s);

}  // namespace lidarsim::qualify
