#pragma once
// Double-precision reference losses of the heads (nn/loss.h), written from the formulas in the
// header, per cell: the tests sum m * cell / denominator and differentiate that numerically.
#include <algorithm>
#include <cmath>

namespace lidarsim::nn::reference {

// -[y log sigmoid(z) + (1 - y) log(1 - sigmoid(z))], through log1p on the smaller term.
inline double bce_cell(double z, double y) {
  const double log_p = z >= 0 ? -std::log1p(std::exp(-z)) : z - std::log1p(std::exp(z));    // log sigmoid(z)
  const double log_q = z >= 0 ? -z - std::log1p(std::exp(-z)) : -std::log1p(std::exp(z));  // log sigmoid(-z)
  return -(y * log_p + (1 - y) * log_q);
}

inline double gaussian_nll_cell(double mu, double s, double y, double lo, double hi) {
  const double sigma = std::exp(std::clamp(s, lo, hi));
  return std::log(sigma) + 0.5 * (y - mu) * (y - mu) / (sigma * sigma) + 0.5 * std::log(2 * M_PI);
}

inline double laplace_nll_cell(double mu, double s, double y, double lo, double hi) {
  const double b = std::exp(std::clamp(s, lo, hi));
  return std::log(b) + std::abs(y - mu) / b + std::log(2.0);
}

}  // namespace lidarsim::nn::reference
