#include "train/data_parallel.h"

#include <cstdint>

#include "nn/loss.h"
#include "train/trainer.h"

namespace lidarsim::train {

double data_parallel_gradients(nn::UNet& model, const nn::Tensor& x, const nn::Tensor& y, const nn::Tensor& m,
                               const std::string& read_error, nn::Tensor& pred, nn::Tensor& d_pred, bool& stop) {
  Distributed& dist = Distributed::world();
  std::int64_t valid = 0;
  if (read_error.empty())
    for (const float v : m) valid += v != 0.f;
  dist.sum(&valid, 1);
  std::string error = read_error;
  double status[3] = {0, error.empty() ? 0.0 : 1.0, stop_requested().load() ? 1.0 : 0.0};  // loss, failed ranks, stops
  if (error.empty()) {
    try {
      model.forward(x, pred);
      status[0] = nn::masked_mse(pred, y, m, &d_pred, static_cast<long>(valid)).data;
      model.backward(d_pred);
    } catch (const std::exception& e) {
      error = *e.what() ? e.what() : "unknown error";
      status[1] = 1;
    }
  }
  dist.sum_in_rank_order(status, 3);
  if (status[1] > 0) dist.agree(error);  // throws on every rank
  dist.sum_in_rank_order(model.params().grads(), model.params().size());
  stop = status[2] > 0;
  return status[0];
}

}  // namespace lidarsim::train
