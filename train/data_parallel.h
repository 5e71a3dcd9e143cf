#pragma once
// Training on several MPI ranks (train/distributed.h): one step's gradients over every rank's
// part of the batch, and actions whose failure on one rank every rank learns of. Internal to
// train/; with one process both are the plain single-process path.
#include <string>

#include "nn/tensor.h"
#include "nn/unet.h"
#include "train/distributed.h"

namespace lidarsim::train {

// One step's gradients over every rank's part of the batch (x, y, m hold this rank's part):
// the loss is normalised by the cells of the whole global batch, the parameter gradients are
// summed in rank order, failures (a frame this rank could not read: `read_error`) and stop
// requests are agreed on before anything changes. Returns the data loss of the whole batch;
// `stop` is set when any rank was asked to stop.
double data_parallel_gradients(nn::UNet& model, const nn::Tensor& x, const nn::Tensor& y, const nn::Tensor& m,
                               const std::string& read_error, nn::Tensor& pred, nn::Tensor& d_pred, bool& stop);

// Runs `f` (no collective calls inside) and agrees with the other ranks on whether it failed.
template <class F>
void agreed(F&& f) {
  Distributed& dist = Distributed::world();
  if (!dist.active()) return f();
  std::string error;
  try {
    f();
  } catch (const std::exception& e) {
    error = *e.what() ? e.what() : "unknown error";
  }
  dist.agree(error);
}

}  // namespace lidarsim::train
