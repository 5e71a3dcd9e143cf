#pragma once
// Terms on the spread of sampled intensity, as `lidar-qualify loop intensity-spread --model CK.h5
// --out-terms T.json` finds them (docs/intensity.md, "The loop on the spread of intensity"): each a
// factor per bin of one feature that multiplies the spread head's scale where the head is off.
// Read by `lidar-infer predict|sim --sample-intensity --spread-terms T.json`.
//
// File: {"format": "lidarsim-intensity-spread-terms", "version": 1, "source": "...",
//        "terms": [{"feature": "class", "width": 1, "factor": [...], "note": "..."}, ...]}
// Features as the loop names them: laser (the map's row), range (m), class, material, azimuth
// (deg, the column's centre), incidence (deg) and intensity, which is the model's predicted MEAN
// (never a measured value).
#include <filesystem>
#include <string>
#include <vector>

#include "pgm/polar_grid_map.h"
#include "sensor/range_noise.h"

namespace lidarsim::infer {

struct IntensitySpreadTerms {
  std::string source;  // the data and command they were found with
  std::vector<sensor::RangeNoiseTerm> terms;
};

// Errors name the file and the field (terms[i].factor, ...).
IntensitySpreadTerms parse_intensity_spread_terms(const std::string& json_text, const std::string& file_name);
IntensitySpreadTerms load_intensity_spread_terms(const std::filesystem::path& path);
std::string intensity_spread_terms_json(const IntensitySpreadTerms& t);

// The product of the terms' factors at a cell of one map. Construction resolves the channels the
// terms read and throws naming one the map lacks (class, material, incidence).
class SpreadTermFactor {
 public:
  SpreadTermFactor(const std::vector<sensor::RangeNoiseTerm>& terms, const pgm::PolarGridMap& map);
  double at(std::size_t cell, double mean) const;  // mean: the model's predicted mean there

 private:
  const std::vector<sensor::RangeNoiseTerm>& terms_;
  const pgm::PolarGridMap& map_;
  const float *range_ = nullptr, *cls_ = nullptr, *material_ = nullptr, *incidence_ = nullptr;
};

}  // namespace lidarsim::infer
