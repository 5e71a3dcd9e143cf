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
#include <string>
#include <vector>

#include "pgm/polar_grid_map.h"

namespace lidarsim::sensor {

struct RangeNoiseModel {
  std::string sensor;  // beam layout name the model was fitted for
  std::string source;  // the data and command it was fitted with
  double a = 0;        // m
  double b = 0;        // m per m of range
  std::vector<double> table_range_m, table_sigma_m;  // bin centres (increasing) and the spread there
  double sigma(double range_m) const;  // m
  void validate(const std::string& where) const;  // throws naming `where` and the field
};

RangeNoiseModel load_range_noise_model(const std::filesystem::path& path);
RangeNoiseModel parse_range_noise_model(const std::string& json_text, const std::string& file_name);

// A standard normal deviate that depends only on its arguments (splitmix64 of the key, then
// Box-Muller).
double range_noise_normal(std::uint64_t seed, std::uint64_t frame, std::uint64_t cell);

// Moves every return of `map` (mask > 0) along its beam by sigma(range) x
// range_noise_normal(seed, frame, cell): the range channel and, when present, x, y, z and height
// (sensor frame, scaled by the same factor, so the point stays on its beam). A range never drops
// below 1 mm. Returns the number of returns moved.
int apply_range_noise(const RangeNoiseModel& model, std::uint64_t seed, std::uint64_t frame, pgm::PolarGridMap& map);

}  // namespace lidarsim::sensor
