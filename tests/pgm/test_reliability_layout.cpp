// Beam layouts too large to be a real sensor are an error before anything is allocated.
#include <gtest/gtest.h>

#include <string>

#include "common/error.h"
#include "pgm/beam_layout.h"

using namespace lidarsim;

namespace {

std::string error_of(auto&& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(LayoutReliability, AbsurdColumnAndRowCountsAreAnError) {
  EXPECT_EQ(error_of([] { pgm::BeamLayout::hdl64e(2048); }), "");
  EXPECT_NE(error_of([] { pgm::BeamLayout::hdl64e(1 << 20); }).find("columns"), std::string::npos);
  EXPECT_NE(error_of([] { pgm::BeamLayout::uniform(100000000, 2, -24, 1024); }).find("rows"), std::string::npos);
}

TEST(LayoutReliability, DifferenceNamesWhatDiffers) {
  const auto a = pgm::BeamLayout::hdl64e(1024), b = pgm::BeamLayout::hdl64e(512);
  EXPECT_EQ(a.difference(a), "");
  EXPECT_EQ(a.difference(b), "columns 1024 vs 512");
  const auto c = pgm::BeamLayout::uniform(32, 2, -24, 1024);
  EXPECT_NE(a.difference(c).find("rows 64 vs 32"), std::string::npos) << a.difference(c);
}

// Found by fuzzing (fuzz/regressions/sensor_layout/, UBSan): "columns": 1e29 was cast to int
// before it was checked (undefined behaviour); counts are now checked as numbers first.
TEST(LayoutReliability, CountsBeyondIntOrFractionalAreAnErrorNamingTheKey) {
  const std::string huge = error_of([] {
    pgm::BeamLayout::from_json(R"({"columns": 1e29, "elevations_deg": [2, 1]})", "layout.json");
  });
  EXPECT_NE(huge.find("layout.json: columns"), std::string::npos) << huge;
  const std::string rows = error_of([] {
    pgm::BeamLayout::from_json(R"({"columns": 64, "rows": 31.5, "top_deg": 2, "bottom_deg": -20})", "layout.json");
  });
  EXPECT_NE(rows.find("layout.json: rows"), std::string::npos) << rows;
  EXPECT_NE(error_of([] { pgm::BeamLayout::from_json(R"({"name": 3, "columns": 64, "rows": 2, "top_deg": 2, "bottom_deg": -2})"); })
                .find("name"),
            std::string::npos);
}
