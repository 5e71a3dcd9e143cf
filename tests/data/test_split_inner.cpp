// The inner region of early stopping (data/split.h inner_split): carved out of the training
// columns, never touching the scored regions or their guard bands, and no input column is seen by
// two of {training cell, inner cell, scored cell}.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "common/error.h"
#include "data/split.h"

using namespace lidarsim;

namespace {

int circular_distance(int a, int b, int n) {
  const int d = std::abs(a - b) % n;
  return std::min(d, n - d);
}

std::vector<int> columns_with(const std::vector<std::uint8_t>& roles, data::Role role) {
  std::vector<int> out;
  for (int c = 0; c < static_cast<int>(roles.size()); ++c)
    if (roles[c] == role) out.push_back(c);
  return out;
}

}  // namespace

TEST(InnerSplit, Depth3LayoutAt1024Columns) {
  const auto scored = data::guarded_split(51, 1024);
  const auto inner = data::inner_split(scored, 51, 1024, 32);
  ASSERT_EQ(inner.regions.size(), 1u);
  EXPECT_EQ(std::lround(inner.regions[0].first * 1024), 294);  // right after region 1's guard [192, 294)
  EXPECT_EQ(std::lround(inner.regions[0].second * 1024), 326);
  EXPECT_EQ(inner.guard_columns, 102);
  const auto roles = data::with_inner(scored, inner).roles(1024);
  EXPECT_EQ(std::count(roles.begin(), roles.end(), data::kTrain), 226);  // [428, 474) and [806, 986)
  EXPECT_EQ(roles[427], data::kGuard);
  EXPECT_EQ(roles[428], data::kTrain);
  EXPECT_EQ(roles[473], data::kTrain);
  EXPECT_EQ(roles[474], data::kGuard);
}

TEST(InnerSplit, NeverTouchesTheScoredRegionsAndNoInputColumnIsShared) {
  for (const int cols : {256, 1024, 2048})
    for (const int half : {2, 9, 23, 51})
      for (const int width : {8, 32}) {
        data::SectorSplit scored, inner;
        try {
          scored = data::guarded_split(half, cols);
          inner = data::inner_split(scored, half, cols, width);
        } catch (const Error&) {
          continue;  // does not fit (checked below for the layouts that must)
        }
        const auto scored_roles = scored.roles(cols);
        const auto inner_roles = inner.roles(cols);
        const auto train_roles = data::with_inner(scored, inner).roles(cols);
        const auto inner_cells = columns_with(inner_roles, data::kValidation);
        const auto inner_band = columns_with(inner_roles, data::kGuard);
        const auto scored_cells = columns_with(scored_roles, data::kValidation);
        const auto training = columns_with(train_roles, data::kTrain);
        ASSERT_EQ(static_cast<int>(inner_cells.size()), width);
        ASSERT_GE(static_cast<int>(training.size()), width) << cols << " " << half;
        // The inner region lies in the scored split's training columns: never in a scored
        // region or its guard bands; its guard bands never reach a scored region.
        for (int c : inner_cells) ASSERT_EQ(scored_roles[c], data::kTrain) << c;
        for (int c : inner_band) ASSERT_NE(scored_roles[c], data::kValidation) << c;
        // The network does not train in the inner region or its guard bands.
        for (int c : inner_cells) ASSERT_NE(train_roles[c], data::kTrain) << c;
        for (int c : inner_band) ASSERT_NE(train_roles[c], data::kTrain) << c;
        // Receptive fields of half-width h: inner vs scored and inner vs training cells share no column.
        for (int i : inner_cells) {
          for (int s : scored_cells) ASSERT_GT(circular_distance(i, s, cols), 2 * half) << i << " " << s;
          for (int t : training) ASSERT_GT(circular_distance(i, t, cols), 2 * half) << i << " " << t;
        }
        // Scored cells stay scored; the scored split's own guarantee still holds.
        for (int s : scored_cells) ASSERT_EQ(train_roles[s], data::kValidation);
        for (int t : training)
          for (int s : scored_cells) ASSERT_GT(circular_distance(t, s, cols), 2 * half);
      }
  EXPECT_NO_THROW(data::inner_split(data::guarded_split(51, 1024), 51, 1024, 32));
  EXPECT_NO_THROW(data::inner_split(data::guarded_split(9, 256), 9, 256, 8));
}

TEST(InnerSplit, RefusesSplitsWithoutGuardedRegionsAndRegionsThatDoNotFit) {
  EXPECT_THROW(data::inner_split(data::reference_split(), 51, 1024), Error);  // no guard: leaks
  EXPECT_THROW(data::inner_split(data::parse_split("frames:000003", 51), 51, 1024), Error);
  EXPECT_THROW(data::inner_split(data::guarded_split(9, 1024), 51, 1024), Error);  // guard narrower than 2 h
  // Depth 3: the 180-column arcs hold 32 + 102 + 32, not 64 + 102 + 64.
  EXPECT_THROW(data::inner_split(data::guarded_split(51, 1024), 51, 1024, 64), Error);
  EXPECT_THROW(data::inner_split(data::guarded_split(51, 1024), 51, 1024, 0), Error);
}

TEST(InnerSplit, FrameHoldOutTakesWholeTrainingFramesOfOtherPlaces) {
  const auto scored = data::parse_split("frames:000000,000003", 51);
  const auto inner = data::inner_frames_split(scored, {"000001"});
  const auto training = data::with_inner(scored, inner);
  EXPECT_EQ(inner.roles(4, "kitti/000001")[2], data::kValidation);
  EXPECT_EQ(inner.roles(4, "kitti/000003")[2], data::kTrain);  // scored frames are not inner
  EXPECT_EQ(training.roles(4, "kitti/000001")[0], data::kValidation);
  EXPECT_EQ(training.roles(4, "kitti/000003")[0], data::kValidation);
  EXPECT_EQ(training.roles(4, "kitti/000002")[0], data::kTrain);
  EXPECT_THROW(data::inner_frames_split(scored, {"000003"}), Error);     // a scored frame
  EXPECT_THROW(data::inner_frames_split(scored, {"kitti/000000"}), Error);  // names one too
  EXPECT_THROW(data::inner_frames_split(scored, {}), Error);
  EXPECT_THROW(data::inner_frames_split(data::guarded_split(51, 1024), {"000001"}), Error);
}
