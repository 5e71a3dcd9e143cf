#include "data/split.h"

#include <algorithm>
#include <string>

#include "common/error.h"

namespace lidarsim::data {

int SectorSplit::sector_of(int column, int columns) const {
  if (sectors < 1 || columns < sectors || columns % sectors != 0)
    throw Error("split: columns: " + std::to_string(columns) + " is not a multiple of the " +
                std::to_string(sectors) + " sectors");
  if (column < 0 || column >= columns) throw Error("split: column " + std::to_string(column) + " out of range");
  return column / (columns / sectors);
}

bool SectorSplit::is_validation(int column, int columns) const {
  const int s = sector_of(column, columns);
  return std::find(validation.begin(), validation.end(), s) != validation.end();
}

std::vector<std::uint8_t> SectorSplit::validation_columns(int columns) const {
  std::vector<std::uint8_t> out(columns);
  for (int c = 0; c < columns; ++c) out[c] = is_validation(c, columns) ? 1 : 0;
  return out;
}

}  // namespace lidarsim::data
