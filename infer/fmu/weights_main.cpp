// lidarsim_fmu_weights <checkpoint.h5> <out.weights>: a lidar-train checkpoint's model as a
// weights file (nn/checkpoint_weights.h), value for value, with its /config attributes (input
// encoder, beam layout). The FMU's build runs it so the FMU reads its UNet without HDF5.
#include <cstdio>
#include <exception>

#include "nn/checkpoint.h"
#include "nn/checkpoint_weights.h"

int main(int argc, char** argv) {
  if (argc != 3) {
    std::fprintf(stderr, "usage: %s <checkpoint.h5> <out.weights>\n", argv[0]);
    return 2;
  }
  try {
    const lidarsim::nn::Checkpoint meta = lidarsim::nn::read_checkpoint_meta(argv[1]);
    lidarsim::nn::UNet model(meta.unet);
    lidarsim::nn::load_checkpoint(argv[1], model, nullptr);
    lidarsim::nn::save_weights(argv[2], model, meta.attributes);
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
}
