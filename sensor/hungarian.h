#pragma once
// Minimum-cost assignment (Hungarian / Kuhn-Munkres with potentials, O(n^2 m)) for rectangular
// cost matrices. Used by the tracker to associate detections with tracks and by the KPI
// calibration to match ground truth with detections.
#include <Eigen/Core>

#include <vector>

namespace lidarsim::sensor {

// Reusable buffers so that per-frame association does not allocate once they have grown.
class HungarianSolver {
 public:
  // cost: rows x cols, finite. Returns for each row the assigned column or -1 (when rows >
  // cols, some rows stay unassigned). The total cost over assigned pairs is minimal.
  const std::vector<int>& solve(const Eigen::MatrixXd& cost);
  double total_cost() const { return total_; }

 private:
  std::vector<double> u_, v_, minv_;
  std::vector<int> p_, way_, assignment_;
  std::vector<char> used_;
  Eigen::MatrixXd transposed_;
  double total_ = 0;
};

// Convenience wrapper (allocates).
std::vector<int> solve_assignment(const Eigen::MatrixXd& cost);

}  // namespace lidarsim::sensor
