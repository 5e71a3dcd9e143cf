#include <gtest/gtest.h>

#include "common/error.h"
#include "pgm/polar_grid_map.h"

using namespace lidarsim::pgm;

TEST(PolarGridMap, ChannelsAreNamedZeroedAndCellsStartEmpty) {
  PolarGridMap m(BeamLayout::uniform(4, 2, -2, 32), {"range", "class"});
  EXPECT_EQ(m.rows(), 4);
  EXPECT_EQ(m.cols(), 32);
  EXPECT_EQ(m.channel_index("class"), 1);
  EXPECT_TRUE(m.has_channel("range"));
  EXPECT_FALSE(m.has_channel("intensity"));
  for (float v : m.data()) EXPECT_EQ(v, 0.f);
  for (auto i : m.point_index()) EXPECT_EQ(i, -1);
  m.at(1, 2, 3) = 7.f;
  EXPECT_EQ(m.channel("class")[2 * 32 + 3], 7.f);
}

TEST(PolarGridMap, AddedChannelKeepsExistingValues) {
  PolarGridMap m(BeamLayout::uniform(2, 1, -1, 8), {"range"});
  m.at(0, 1, 5) = 3.f;
  EXPECT_EQ(m.add_channel("incidence"), 1);
  EXPECT_EQ(m.at(0, 1, 5), 3.f);
  EXPECT_EQ(m.at(1, 1, 5), 0.f);
}

TEST(PolarGridMap, UnknownOrDuplicateChannelThrowsNamingIt) {
  PolarGridMap m(BeamLayout::uniform(2, 1, -1, 8), {"range"});
  try {
    m.channel_index("height");
    FAIL();
  } catch (const lidarsim::Error& e) {
    EXPECT_NE(std::string(e.what()).find("height"), std::string::npos);
  }
  EXPECT_THROW(m.add_channel("range"), lidarsim::Error);
}
