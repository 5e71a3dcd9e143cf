#pragma once
// Return model (raydrop): the probability that the sensor returns a point from a cell whose beam
// meets geometry, as a smoothed table over laser (PGM row) x range bin x class, fitted on the
// cells of measured scans that pgm::return_target says had geometry.
//
// Shrinkage: each table entry is a beta-binomial posterior mean whose prior is the entry one
// level coarser, with `prior_strength` pseudo-cells:
//   global -> laser -> laser x range -> laser x range x class
// and, for sensors other than the one fitted (per-laser entries do not transfer between
// sensors), the laser-free chain global -> range -> range x class. An entry with few cells thus
// stays near its margin; one with many follows its own data. Class 0 (unlabeled) and classes
// with no cells use the laser x range entry.
//
// In simulation, a cell with a return is kept when u < p, where u in [0, 1) is a counter-based
// hash of (seed, frame, cell): a draw depends on nothing else, so any thread order and any
// other random stream leave it unchanged.
//
// JSON (data/models/returns_*.json):
//   {"format": "lidarsim-returns", "version": 1, "layout": {beam layout}, "range_bin_m": 5,
//    "range_bins": 24, "classes": [class names], "prior_strength": 20, "source": "...",
//    "fit_command": "...", "fit_places": [...], counts and probabilities per level}
#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "pgm/beam_layout.h"
#include "pgm/polar_grid_map.h"
#include "pgm/return_target.h"

namespace lidarsim::sensor {

// Counts of geometry cells and of their returns per laser x range bin x class.
struct ReturnCounts {
  int rows = 0, range_bins = 24, classes = 0;
  double range_bin_m = 5;
  std::vector<double> cells, returns;  // [rows * range_bins * classes]

  ReturnCounts() = default;
  ReturnCounts(int rows, int classes, double range_bin_m = 5, int range_bins = 24);
  int range_bin(double range_m) const;  // clamped to the last bin
  std::size_t index(int row, int bin, int class_id) const {
    return (static_cast<std::size_t>(row) * range_bins + bin) * classes + class_id;
  }
  void add(int row, double range_m, int class_id, bool returned);
  // Every Return and Drop cell of a target (Sky cells say nothing about returns).
  void add(const pgm::ReturnTarget& target);
  void merge(const ReturnCounts& other);  // same shape, else lidarsim::Error
};

// A multiplier term the closed loop adds (qualify/returns/returns_loop.h): p' = factor(key(cell)) x p,
// clamped to [0, 1]. Keys, the same in the loop and the simulation:
//   laser (row), range_5m (24 bins), class, material (the class's default), azimuth_10deg (36),
//   azimuth_5deg (72), height_0.5m (sensor-frame z = range x sin(elevation), 20 bins from -3 m),
//   class_x_range_5m (class x 24).
// Azimuth is the column centre 360 (col + 0.5) / columns.
enum class ReturnKey { Laser, Range5m, Class, Material, Azimuth10, Azimuth5, Height, ClassRange5m };
const char* to_string(ReturnKey key);
ReturnKey return_key_from_string(const std::string& name, const std::string& where);  // throws naming the file
int return_key_size(ReturnKey key, int rows);
int return_key(ReturnKey key, int row, double range_m, int class_id, double azimuth_deg, double height_m);

struct ReturnMultiplier {
  ReturnKey key = ReturnKey::Laser;
  std::vector<float> factor;  // [return_key_size]
  std::string note;           // what the loop found (feature, form, its held-out cut)
};

class ReturnModel {
 public:
  ReturnModel() = default;
  // Fits the shrunk tables from counts on `layout` (rows must agree).
  static ReturnModel fit(const ReturnCounts& counts, const pgm::BeamLayout& layout, double prior_strength = 20);

  // P(return | geometry) of a cell; use_laser = false uses the laser-free chain.
  float probability(int row, double range_m, int class_id, bool use_laser = true) const;

  // The probability with the multiplier terms (col: the PGM column); the same as probability()
  // when there are none.
  float probability_at(int row, int col, double range_m, int class_id) const;
  std::vector<ReturnMultiplier> multipliers;  // JSON "multipliers" (optional; absent = none)

  const pgm::BeamLayout& layout() const { return layout_; }
  int rows() const { return counts_.rows; }
  double prior_strength() const { return prior_; }
  const ReturnCounts& counts() const { return counts_; }

  std::string source, fit_command;        // recorded in the JSON
  std::vector<std::string> fit_places;    // places whose scans were counted

  nlohmann::json to_json() const;
  static ReturnModel from_json(const nlohmann::json& j, const std::string& where);
  static ReturnModel load(const std::string& path);  // throws naming the file and field
  void save(const std::string& path) const;          // atomic

 private:
  pgm::BeamLayout layout_;
  ReturnCounts counts_;
  double prior_ = 20;
  double global_ = 1;
  std::vector<float> laser_, laser_range_, laser_range_class_;  // [R], [R*B], [R*B*K]
  std::vector<float> range_, range_class_;                      // [B], [B*K]
};

// Uniform [0, 1) draw of (seed, frame, cell): splitmix64 over the three, no state.
double return_draw(std::uint64_t seed, std::uint64_t frame, std::uint64_t cell);

// Drops returns of a generated map with the model (rows must be the model's): cells whose draw is
// not below their probability become empty exactly as a beam that met nothing (range, class,
// material, intensity, mask and effect channels 0, object_id -1, point_index -1). Returns the
// number of cells dropped.
int apply_return_model(const ReturnModel& model, pgm::PolarGridMap& map, std::uint64_t seed, std::uint64_t frame);

}  // namespace lidarsim::sensor
