#pragma once
// Effect forms the intensity loop can add beyond a smooth binned trend, each fitted on the fit
// cells only:
//   - a table over given bins (one bin per beam row: a per-beam offset or gain, where equal-count
//     bins of elevation would merge about four lasers each and smear a per-laser effect);
//   - a window: one contiguous range of a feature's fine bins (equal-count on the fit cells, or
//     one per beam row) with its own level, found by searching every [a, b] range for the largest
//     drop of the fit cells' squared error (a two-level step/box; a step is a window reaching an
//     end). Its edges are the bins' edges, so they are fitted where fit cells exist; an edge that
//     falls where the split has no fit cells (a guard band) lies at the nearest fit value.
#include <vector>

#include "qualify/residual.h"

namespace lidarsim::qualify {

// Edges k + 0.5 between integer categories 0..n-1: one bin per value (beam rows).
std::vector<double> category_edges(int n);

// Least-squares gain per bin with measured ~ gain * base, shrunk towards 1.
BinnedTable fit_gain_table(const std::vector<double>& edges, const std::vector<double>& x,
                           const std::vector<double>& measured, const std::vector<double>& base, double shrink = 5);

// The best window of r over contiguous ranges of `edges`' bins: a BinnedTable with two edges
// (lo, hi) and three bins (below, inside, above; outside bins share one level), or an empty
// table when there are fewer than 3 bins. `inside_bins` gets [a, b] of the fine bins.
BinnedTable fit_window(const std::vector<double>& edges, const std::vector<double>& x, const std::vector<double>& r,
                       double shrink = 5);
// The same window's levels as gains on `base` (measured ~ g_in * base inside, g_out outside).
BinnedTable fit_window_gain(const BinnedTable& window, const std::vector<double>& x,
                            const std::vector<double>& measured, const std::vector<double>& base, double shrink = 5);

// Equal-count edges of x (ties kept together), as fit_binned_mean uses.
std::vector<double> equal_count_edges(const std::vector<double>& x, int bins);

}  // namespace lidarsim::qualify
