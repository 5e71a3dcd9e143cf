#pragma once
// `lidar-qualify range-noise`: fits the range noise of a sensor on its measured labelled scans
// (qualify/range_noise/range_noise_fit.h), prints the spread per range bin beside the datasheet figure, and
// writes the model the PCL generator applies (sensor/range_noise.h) with the measured tables.
//   lidar-qualify range-noise --semantickitti DIR --out data/models/range_noise_hdl64e.json
//   lidar-qualify range-noise --nuscenes-lidarseg DIR --sensor data/sensors/hdl32e-nuscenes.json
//       --class-table data/ontologies/nuscenes-lidarseg.csv --out M.json
//   lidar-qualify range-noise --rellis3d DIR --sensor data/sensors/os1-64-rellis3d.json
//       --class-table data/ontologies/rellis3d.csv --out M.json
#include <string>
#include <vector>

#include "pgm/projection.h"

namespace lidarsim::qualify {

// One labelled scan and the file it came from.
struct LabelledScan {
  std::vector<pgm::Point> points;
  std::string source;
};

// The labelled scans of a folder: dataset "semantickitti" (scans with a label file), or
// "nuscenes-lidarseg" / "rellis3d" with a class table (data/ontologies/*.csv); at most max_scans
// (0: all). Throws naming the folder when none is found.
std::vector<LabelledScan> read_labelled_scans(const std::string& dataset, const std::string& dir,
                                              const std::string& class_table, int max_scans);

// argv[0] is "range-noise"; returns the exit code (throws lidarsim::Error for bad input).
int run_range_noise(int argc, char** argv);

}  // namespace lidarsim::qualify
