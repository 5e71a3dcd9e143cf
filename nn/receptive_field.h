#pragma once
// The receptive field of a UNet (nn/unet.h) from its architecture: how far, in input cells, an
// output cell can see. A validation split must keep training cells out of that reach
// (data/split.h), so it is computed exactly, not estimated.
//
// Computed by propagating, along one axis, the interval of input positions each activation
// depends on through the same graph as UNet::forward: 3x3 convs (padding 1), 2x2 max-pools
// (stride 2), 2x2 transposed convs (stride 2), the skip concatenations and the 1x1 head. The
// half-width is the largest distance from an output cell to an input cell it depends on, over
// positions far from the border (pooling makes the reach depend on the position's parity).
// Kernels are square, so rows and columns have the same half-width.
#include "nn/unet.h"

namespace lidarsim::nn {

int receptive_field_half_width(const UNetConfig& config);

}  // namespace lidarsim::nn
