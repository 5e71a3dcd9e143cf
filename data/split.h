#pragma once
// The reference train/validation split for recorded scans: consecutive scans are nearly
// identical, so whole azimuth sectors are held out instead of scans. The circle is cut into 16
// sectors (64 columns each at 1024 columns, 128 at 2048); sectors 3, 7, 11 and 15 are validation
// in every scan, the rest training. Interleaved so every direction around the car appears on
// both sides; sector s covers columns [s * columns / 16, (s + 1) * columns / 16).
#include <cstdint>
#include <vector>

namespace lidarsim::data {

struct SectorSplit {
  int sectors = 16;
  std::vector<int> validation = {3, 7, 11, 15};

  int sector_of(int column, int columns) const;  // throws unless columns is a multiple of sectors
  bool is_validation(int column, int columns) const;
  // Per column: 1 = validation, 0 = training.
  std::vector<std::uint8_t> validation_columns(int columns) const;
};

// The reference split above.
inline SectorSplit reference_split() { return {}; }

}  // namespace lidarsim::data
