#include "train/early_stop.h"

namespace lidarsim::train {

bool EarlyStop::add(double inner_mae) {
  losses_.push_back(inner_mae);
  const bool better = inner_mae == inner_mae && (best_ == 0 || inner_mae < losses_[best_ - 1]);
  if (better) best_ = static_cast<int>(losses_.size());
  return better;
}

bool EarlyStop::exhausted() const {
  return patience_ > 0 && static_cast<int>(losses_.size()) - best_ >= patience_;
}

}  // namespace lidarsim::train
