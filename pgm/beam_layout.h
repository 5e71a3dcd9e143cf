#pragma once
// A sensor's beam layout as data: the elevation of each row (beam) and the azimuth binning.
// Row 0 is the top beam (highest elevation), rows grow downwards, as in a range image.
// Column = floor(az / 2pi * columns), az = atan2(y, x) mod 2pi: column 0 looks straight ahead
// and columns grow to the left (counter-clockwise seen from above).
#include <string>
#include <vector>

namespace lidarsim::pgm {

struct BeamLayout {
  std::string name;                    // e.g. "hdl64e", "uniform"
  std::vector<double> elevations_rad;  // one per row, descending (row 0 = top)
  int columns = 1024;                  // azimuth bins over 360 degrees

  int rows() const { return static_cast<int>(elevations_rad.size()); }
  // Uniform spacing from top to bottom elevation (degrees at the edge, radians inside).
  static BeamLayout uniform(int rows, double top_deg, double bottom_deg, int columns);
  // Velodyne HDL-64E as mounted on KITTI (approximately +2 to -24.9 deg).
  static BeamLayout hdl64e(int columns = 1024);
  int column_of(double x, double y) const;  // azimuth bin of a direction
  double azimuth_of_column(int col) const;  // centre of a bin, radians in [0, 2pi)
};

}  // namespace lidarsim::pgm
