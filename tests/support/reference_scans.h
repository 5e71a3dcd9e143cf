#pragma once
// The reference sensor's scans (data/reference_sensor.h) written to a temporary folder and read
// back as lidar-qualify reads them: the intensity loop's tests start from these.
#include <filesystem>
#include <string>

#include "data/reference_sensor.h"
#include "qualify/intensity/intensity.h"
#include "tests/support/temp_path.h"

namespace lidarsim::testing {

inline data::Dataset reference_scans(const data::ReferenceScanOptions& options, const std::string& name) {
  const std::filesystem::path dir = temp_path(name);
  std::filesystem::remove_all(dir);
  data::write_reference_semantickitti(dir, options);
  data::Dataset ds = qualify::import_for_qualify(dir);
  std::filesystem::remove_all(dir);
  return ds;
}

}  // namespace lidarsim::testing
