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
