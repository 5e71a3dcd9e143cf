#include "sensor/hungarian.h"

#include <cmath>
#include <limits>

#include "common/error.h"

namespace lidarsim::sensor {

const std::vector<int>& HungarianSolver::solve(const Eigen::MatrixXd& cost_in) {
  const int rows = static_cast<int>(cost_in.rows()), cols = static_cast<int>(cost_in.cols());
  assignment_.assign(rows, -1);
  total_ = 0;
  if (rows == 0 || cols == 0) return assignment_;
  if (!cost_in.allFinite()) throw Error("hungarian: cost matrix: must be finite");
  // The potential method needs n <= m; solve the transposed problem when there are more rows.
  const bool transpose = rows > cols;
  const Eigen::MatrixXd* cost = &cost_in;
  if (transpose) {
    transposed_ = cost_in.transpose();
    cost = &transposed_;
  }
  const int n = static_cast<int>(cost->rows()), m = static_cast<int>(cost->cols());
  const double inf = std::numeric_limits<double>::infinity();
  u_.assign(n + 1, 0.0);
  v_.assign(m + 1, 0.0);
  p_.assign(m + 1, 0);    // p_[j]: row (1-based) assigned to column j; column 0 is a sentinel
  way_.assign(m + 1, 0);
  for (int i = 1; i <= n; ++i) {
    p_[0] = i;
    int j0 = 0;
    minv_.assign(m + 1, inf);
    used_.assign(m + 1, 0);
    do {  // grow an alternating tree from row i until it reaches a free column
      used_[j0] = 1;
      const int i0 = p_[j0];
      double delta = inf;
      int j1 = 0;
      for (int j = 1; j <= m; ++j) {
        if (used_[j]) continue;
        const double cur = (*cost)(i0 - 1, j - 1) - u_[i0] - v_[j];
        if (cur < minv_[j]) {
          minv_[j] = cur;
          way_[j] = j0;
        }
        if (minv_[j] < delta) {
          delta = minv_[j];
          j1 = j;
        }
      }
      for (int j = 0; j <= m; ++j) {
        if (used_[j]) {
          u_[p_[j]] += delta;
          v_[j] -= delta;
        } else {
          minv_[j] -= delta;
        }
      }
      j0 = j1;
    } while (p_[j0] != 0);
    do {  // flip the augmenting path
      const int j1 = way_[j0];
      p_[j0] = p_[j1];
      j0 = j1;
    } while (j0);
  }
  for (int j = 1; j <= m; ++j) {
    if (p_[j] == 0) continue;
    const int r = p_[j] - 1, c = j - 1;
    if (transpose) assignment_[c] = r;
    else assignment_[r] = c;
    total_ += (*cost)(r, c);
  }
  return assignment_;
}

std::vector<int> solve_assignment(const Eigen::MatrixXd& cost) {
  HungarianSolver solver;
  return solver.solve(cost);
}

}  // namespace lidarsim::sensor
