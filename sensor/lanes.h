#pragma once
// Lanes: each visible lane marking as a cubic y(x) = c0 + c1 x + c2 x^2 + c3 x^3 in the sensor
// frame, least squares over its points, valid on [x_min, x_max] of those points. x is scaled to
// [-1, 1] for the solve (conditioning at 100 m ranges) and the coefficients mapped back. With
// fewer than 4 points the degree drops (3 points: quadratic, 2: line). A marking spanning less
// than min_x_span in x (e.g. one that runs across the view) is not a function of x: skipped.
#include <vector>

#include "sensor/scene.h"

namespace lidarsim::sensor {

struct LaneFitConfig {
  double min_x_span = 2.0;  // m
  int min_points = 2;
};

// false when the polyline cannot be fitted (too few points or too short in x).
bool fit_lane(const LanePolyline& lane, LanePolynomial& out, const LaneFitConfig& config = {});
// All fittable lanes, in order; out is reused.
void fit_lanes(const std::vector<LanePolyline>& lanes, std::vector<LanePolynomial>& out, const LaneFitConfig& config = {});
double evaluate(const LanePolynomial& p, double x);

}  // namespace lidarsim::sensor
