#pragma once
// Early stopping on an inner validation region (data/split.h, inner_split): the epoch is chosen
// by the MAE on cells carved out of the training columns, never by the scored validation, and the
// weights of that epoch are kept (no retraining). The scored validation is then measured once.
#include <vector>

namespace lidarsim::train {

class EarlyStop {
 public:
  // patience: stop once this many epochs in a row brought no new best (0: run every epoch).
  explicit EarlyStop(int patience = 0) : patience_(patience) {}
  // Records the next epoch's inner MAE; true when it is the new best (strictly lower than every
  // earlier one: a tie keeps the earlier epoch; NaN is never best).
  bool add(double inner_mae);
  int best_epoch() const { return best_; }  // 1-based; 0 before any finite loss
  double best_loss() const { return best_ > 0 ? losses_[best_ - 1] : 0.0; }
  bool exhausted() const;
  const std::vector<double>& losses() const { return losses_; }

 private:
  int patience_;
  int best_ = 0;
  std::vector<double> losses_;
};

}  // namespace lidarsim::train
