#include <algorithm>
#include <cmath>
#include <map>
#include <utility>

#include "qualify/returns/returns.h"

namespace lidarsim::qualify {

namespace {

// Per group: cells, measured returns, sum of predicted p; for both column halves too.
struct Group {
  double n = 0, y = 0, p = 0;
  double n_half[2] = {0, 0}, y_half[2] = {0, 0};
};

double tv(const std::map<int, Group>& groups, double total) {
  double s = 0;
  for (const auto& [k, g] : groups) s += g.n / total * std::abs(g.p / g.n - g.y / g.n);
  return s;
}

// TV between the two halves' rates, each group weighted by its share of the cells.
double tv_halves(const std::map<int, Group>& groups, double total) {
  double s = 0;
  for (const auto& [k, g] : groups)
    if (g.n_half[0] > 0 && g.n_half[1] > 0) s += g.n / total * std::abs(g.y_half[0] / g.n_half[0] - g.y_half[1] / g.n_half[1]);
  return s;
}

}  // namespace

ReturnScore score_returns(const std::vector<pgm::ReturnTarget>& targets, const sensor::ReturnModel* model,
                          bool use_laser, double range_bin_m) {
  ReturnScore s;
  std::map<int, Group> laser, range, cls;
  std::vector<std::pair<float, bool>> cells;
  double brier = 0, sum_p = 0, sum_y = 0;
  for (const auto& t : targets)
    for (std::size_t i = 0; i < t.label.size(); ++i) {
      if (t.label[i] == pgm::ReturnLabel::Sky) continue;
      const int row = static_cast<int>(i / t.cols), col = static_cast<int>(i % t.cols);
      const bool y = t.label[i] == pgm::ReturnLabel::Return;
      const float p = model ? model->probability(row, t.range[i], t.class_id[i], use_laser) : 1.f;
      cells.emplace_back(p, y);
      brier += (p - y) * (p - y);
      sum_p += p;
      sum_y += y;
      const int half = (col / 32) % 2;
      const int keys[3] = {row, static_cast<int>(t.range[i] / range_bin_m), t.class_id[i]};
      std::map<int, Group>* maps[3] = {&laser, &range, &cls};
      for (int m = 0; m < 3; ++m) {
        Group& g = (*maps[m])[keys[m]];
        g.n += 1, g.y += y, g.p += p;
        g.n_half[half] += 1, g.y_half[half] += y;
      }
    }
  s.cells = static_cast<long long>(cells.size());
  if (cells.empty()) return s;
  const double n = static_cast<double>(cells.size());
  s.measured_rate = sum_y / n;
  s.predicted_rate = sum_p / n;
  s.brier = brier / n;
  s.tv_laser = tv(laser, n), s.tv_range = tv(range, n), s.tv_class = tv(cls, n);
  s.tv_laser_halves = tv_halves(laser, n), s.tv_range_halves = tv_halves(range, n), s.tv_class_halves = tv_halves(cls, n);
  // AUROC with ties counted half: ascending p, groups of equal p.
  std::sort(cells.begin(), cells.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  const double pos = sum_y, neg = n - sum_y;
  if (pos > 0 && neg > 0) {
    double auc = 0, neg_below = 0;
    for (std::size_t a = 0; a < cells.size();) {
      std::size_t b = a;
      double gp = 0, gn = 0;
      while (b < cells.size() && cells[b].first == cells[a].first) (cells[b].second ? gp : gn) += 1, ++b;
      auc += gp * neg_below + 0.5 * gp * gn;
      neg_below += gn;
      a = b;
    }
    s.auroc = auc / (pos * neg);
  }
  return s;
}

nlohmann::json to_json(const ReturnScore& s) {
  return {{"cells", s.cells},
          {"measured_rate", s.measured_rate},
          {"predicted_rate", s.predicted_rate},
          {"auroc", s.auroc},
          {"brier", s.brier},
          {"tv_laser", s.tv_laser},
          {"tv_range_5m", s.tv_range},
          {"tv_class", s.tv_class},
          {"tv_laser_halves", s.tv_laser_halves},
          {"tv_range_5m_halves", s.tv_range_halves},
          {"tv_class_halves", s.tv_class_halves}};
}

}  // namespace lidarsim::qualify
