#pragma once
// Range noise of a real sensor: each return's range scatters along its beam (Gaussian) with a
// spread that depends on range. Fitted on measured scans by `lidar-qualify range-noise`
// (qualify/range_noise/range_noise_fit.h, docs/range-noise.md) and stored as JSON:
//   {"format": "lidarsim-range-noise", "version": 1, "sensor": "hdl64e", "source": "...",
//    "sigma_m": {"a": 0.0074, "b": 0.00056},
//    "table": {"range_m": [2.5, 7.5, ...], "sigma_m": [0.0083, 0.0084, ...]}, ...}
// sigma(r) is the measured table when there is one: flat below its first range, linear between
// its ranges, and beyond its last range the last value grown as the smooth form
// sqrt(a^2 + (b r)^2) grows; without a table, the smooth form. Other keys (the measured tables
// by incidence, class, ...) are kept for people and ignored here.
//
// The draws are counter-based: the normal deviate of a cell depends only on (seed, frame, cell),
// so a run is reproducible whatever the thread count or the order the cells are visited in, and
// rows of a campaign that share a seed and frame see the same noise.
#include <cstdint>
#include <filesystem>
#include <limits>
#include <string>
#include <vector>

#include "pgm/polar_grid_map.h"

namespace lidarsim::sensor {

// What a spread term may depend on, for one return. NaN incidence or intensity: not known (factor 1).
struct RangeNoiseFeatures {
  double range_m = 0;
  int row = 0;             // beam row (laser), 0 = top
  int class_id = 0;        // pgm::cls
  int material = 0;        // pgm::material
  double azimuth_deg = 0;  // [0, 360), the PGM's columns' convention
  double incidence_rad = std::numeric_limits<double>::quiet_NaN();
  double intensity = std::numeric_limits<double>::quiet_NaN();
};

// One multiplicative spread term: the feature's value v falls in bin floor(v / width) (clamped to
// the table's ends; wrapped for azimuth), whose factor multiplies the spread.
struct RangeNoiseTerm {
  std::string feature;  // laser | range | class | material | azimuth | incidence (deg) | intensity
  double width = 1;     // bin width in the feature's unit (m, deg, the sensor's intensity scale; 1 for ids)
  std::vector<double> factor;
  std::string note;     // where it came from (the loop's held-out figures)
  double factor_at(const RangeNoiseFeatures& f) const;
};
const std::vector<std::string>& range_noise_term_features();

struct RangeNoiseModel {
  std::string sensor;  // beam layout name the model was fitted for
  std::string source;  // the data and command it was fitted with
  double a = 0;        // m
  double b = 0;        // m per m of range
  std::vector<double> table_range_m, table_sigma_m;  // bin centres (increasing) and the spread there
  std::vector<RangeNoiseTerm> terms;  // version 2; empty: sigma depends on range alone
  double extra_per_m = 0;  // version 2: a spread c r added in quadrature (m per m of range)
  double sigma(double range_m) const;  // m, without the terms
  // m: sqrt(sigma(range)^2 + (extra_per_m range)^2) x every term's factor.
  double sigma_at(const RangeNoiseFeatures& f) const;
  bool has_terms() const { return !terms.empty() || extra_per_m > 0; }
  void validate(const std::string& where) const;  // throws naming `where` and the field
};

RangeNoiseModel load_range_noise_model(const std::filesystem::path& path);
RangeNoiseModel parse_range_noise_model(const std::string& json_text, const std::string& file_name);
// The model as the file holds it (format, version 1 or 2 with terms, sigma_m, table, terms).
std::string range_noise_model_json(const RangeNoiseModel& model);

// A standard normal deviate that depends only on its arguments (splitmix64 of the key, then
// Box-Muller).
double range_noise_normal(std::uint64_t seed, std::uint64_t frame, std::uint64_t cell);

// Moves every return of `map` (mask > 0) along its beam by sigma(range) x
// range_noise_normal(seed, frame, cell): the range channel and, when present, x, y, z and height
// (sensor frame, scaled by the same factor, so the point stays on its beam). A range never drops
// below 1 mm. Returns the number of returns moved. With terms, the spread is sigma_at of the
// cell (row, column centre's azimuth, and the class, material, incidence or intensity channel a
// term reads: a term whose channel the map lacks is an error naming it).
int apply_range_noise(const RangeNoiseModel& model, std::uint64_t seed, std::uint64_t frame, pgm::PolarGridMap& map);

}  // namespace lidarsim::sensor
