// The receptive field computed from the architecture (nn/receptive_field.h) against a brute-force
// measurement on real UNets: with positive weights, zero biases and a zero input, the output is
// exactly 0 except where it depends on a cell that is set to 1 (every path is positive, ReLU and
// max-pool pass it on), so the set of changed outputs is exactly the cell's reach.
#include <gtest/gtest.h>

#include <algorithm>

#include "conv_path.h"
#include "nn/receptive_field.h"
#include "nn/unet.h"

namespace lidarsim::nn {
namespace {

// Largest column distance from a perturbed input column to an output column that changes, over
// 2^depth neighbouring input columns (the reach depends on the position's parity under pooling).
// On the direct 3x3 path: Winograd's tile transforms leave rounding-level values (~1e-8) where the
// exact output is 0, within the 4 x 4 tile around the reach's edge.
int measured_half_width(const UNetConfig& cfg, int rows, int cols) {
  conv_paths::Conv3x3PathGuard direct(detail::Conv3x3Path::direct);
  UNet model(cfg);
  model.init(1);
  ParamArena& arena = model.params();
  for (const ParamInfo& p : arena.infos())
    for (std::size_t i = 0; i < p.shape.numel(); ++i) arena.values()[p.offset + i] = p.decays ? 0.3f : 0.f;
  int reach = 0;
  for (int p = cols / 2; p < cols / 2 + (1 << cfg.depth); ++p) {
    Tensor x(1, cfg.in_channels, rows, cols), y;
    x.at(0, 0, rows / 2, p) = 1.f;
    model.predict(x, y);
    for (int r = 0; r < rows; ++r)
      for (int c = 0; c < cols; ++c)
        if (y.at(0, 0, r, c) != 0.f) reach = std::max(reach, std::abs(c - p));
  }
  return reach;
}

TEST(ReceptiveField, MatchesBruteForceMeasurementForDepths0To4) {
  for (int depth = 0; depth <= 4; ++depth) {
    const UNetConfig cfg{1, 1, 1, depth};
    const int computed = receptive_field_half_width(cfg);
    EXPECT_EQ(computed, measured_half_width(cfg, 1 << depth, 512)) << "depth " << depth;
  }
}

TEST(ReceptiveField, DependsOnDepthNotWidthAndIs51And107ForTheRecipes) {
  EXPECT_EQ(receptive_field_half_width({3, 1, 8, 3}), 51);    // bundled recipe
  EXPECT_EQ(receptive_field_half_width({27, 1, 16, 3}), 51);  // width and inputs do not matter
  EXPECT_EQ(receptive_field_half_width({3, 1, 16, 4}), 107);  // the PyTorch reference's
  EXPECT_EQ(receptive_field_half_width({3, 1, 16, 0}), 2);    // two 3x3 convs
}

}  // namespace
}  // namespace lidarsim::nn
