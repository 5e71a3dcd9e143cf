#pragma once
// The checkpoint readers of nn/checkpoint.h on a checkpoint's bytes in memory: the same checks
// as on a path, without a file (the fuzz target reads each input so). Errors name image.name.
#include "nn/checkpoint.h"
#include "nn/memory_image.h"

namespace lidarsim::nn {

Checkpoint read_checkpoint_meta(const MemoryImage& image);
void load_checkpoint(const MemoryImage& image, UNet& model, Optimizer* optimizer);

}  // namespace lidarsim::nn
