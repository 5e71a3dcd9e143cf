#pragma once
// A sensor's beam layout as data: the elevation of each row (beam) and the azimuth binning.
// Row 0 is the top beam (highest elevation), rows grow downwards, as in a range image.
// Column = floor(az / 2pi * columns), az = atan2(y, x) mod 2pi: column 0 looks straight ahead
// and columns grow to the left (counter-clockwise seen from above).
//
// Layouts travel in checkpoints, datasets and scenarios as JSON (degrees at the edge):
//   {"name": "hdl64e", "columns": 1024, "elevations_deg": [2.61, 2.23, ...]}
// or, for a uniform layout, {"name": "uniform", "columns": 1024, "rows": 32,
//   "top_deg": 15, "bottom_deg": -15} (the explicit list wins when both are given).
// Optional, for sensors described by data (data/sensors/*.json): "azimuth_offsets_deg" (one
// per beam, row order: the beam fires this far from its column's centre, counter-clockwise
// positive, as Ouster's beam_azimuth_angles are clockwise positive with the sign flipped),
// "min_range_m" / "max_range_m" (the sensor's range limits), "sensor" (a free description).
// Written only when set, so layouts without them keep their JSON and compare equal.
#include <string>
#include <vector>

namespace lidarsim::pgm {

struct BeamLayout {
  // Larger grids are no real sensor (an Ouster OS-2 has 128 x 2048): an Error, not an allocation.
  static constexpr int kMaxRows = 1024;
  static constexpr int kMaxColumns = 16384;

  std::string name;                    // e.g. "hdl64e", "uniform"
  std::vector<double> elevations_rad;  // one per row, descending (row 0 = top)
  int columns = 1024;                  // azimuth bins over 360 degrees
  std::vector<double> azimuth_offsets_rad;  // per row, empty = every beam fires at the column centre
  double min_range_m = 0, max_range_m = 0;  // 0 = not given
  std::string sensor;                        // description, e.g. "Ouster OS-1-128, fw v2.3.0"

  double azimuth_offset(int row) const { return azimuth_offsets_rad.empty() ? 0.0 : azimuth_offsets_rad[row]; }

  int rows() const { return static_cast<int>(elevations_rad.size()); }
  // Uniform spacing from top to bottom elevation (degrees at the edge, radians inside).
  static BeamLayout uniform(int rows, double top_deg, double bottom_deg, int columns);
  // Velodyne HDL-64E as mounted on KITTI: the median elevation of each firing-order row measured
  // on KITTI sequence 00 (+2.61 deg to -23.74 deg; the nominal spec is about +2 to -24.9 deg, but
  // KITTI's points are motion-corrected and carry per-laser offsets, so the measured medians are
  // what the rows of a real scan look like).
  static BeamLayout hdl64e(int columns = 1024);
  // Any sensor from its list of elevations in degrees (sorted descending here; must be finite).
  static BeamLayout from_elevations_deg(std::string name, std::vector<double> elevations_deg, int columns);

  int column_of(double x, double y) const;  // azimuth bin of a direction
  double azimuth_of_column(int col) const;  // centre of a bin, radians in [0, 2pi)
  // Row whose elevation is nearest; -1 when the elevation lies more than one row spacing
  // beyond the top or bottom beam.
  int nearest_row(double elevation_rad) const;

  // Throws lidarsim::Error (naming `where`) unless 1 <= rows <= kMaxRows, 1 <= columns <=
  // kMaxColumns, elevations finite and strictly descending, azimuth offsets one per row and
  // finite, 0 <= min_range < max_range.
  void validate(const std::string& where = "beam layout") const;

  std::string to_json() const;  // compact JSON, degrees
  // `where` names the file (or checkpoint attribute) the text came from, for error messages.
  static BeamLayout from_json(const std::string& text, const std::string& where = "beam layout");
  static BeamLayout from_file(const std::string& path);  // a JSON file as above
  bool operator==(const BeamLayout&) const = default;
  // What differs from `other`, this first ("columns 1024 vs 512, rows 64 vs 32"); "" when equal.
  std::string difference(const BeamLayout& other) const;
};

}  // namespace lidarsim::pgm
