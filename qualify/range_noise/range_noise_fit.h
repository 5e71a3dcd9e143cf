#pragma once
// Range noise measured on recorded scans: residuals of local line fits taken along the beam.
//
// For a return p0 of a planar class, its neighbours in the same beam row (half_window on each
// side in azimuth order, no gap wider than gap_factor x the row's median azimuth step, all of
// p0's class) are regressed in a frame aligned with p0's beam: w = p.u against a = p.e, with
// u = p0 / |p0| and e the horizontal unit vector across u, as w = c0 + c1 a. p0 itself sits at
// a = 0, so its range residual is |p0| - c0: a distance ALONG THE BEAM, comparable with a range
// noise. The perpendicular distance to the fitted surface would be smaller by cos(incidence)
// (a road seen at 80 deg would read 0.17 x the noise). Each residual is divided by sqrt(1 + h),
// h the leverage of a = 0 in the neighbours' fit, so a flat surface whose ranges scatter with
// sigma gives residuals of spread sigma.
//
// One row only: a laser's neighbours are a few centimetres apart at 20 m, adjacent lasers on the
// ground metres apart (across them the surface is not flat, and lasers carry their own range
// offsets, which are calibration, not shot noise). Neighbourhoods are rejected when the
// neighbours' own line leaves an RMS above max_neighbour_rms (an edge, clutter) or the residual
// exceeds max_abs_residual; the spread per bin is the robust 1.4826 x MAD, so what remains of
// edges and mixed surfaces weighs little. What a local fit cannot remove is the surface's own
// roughness at the scale of the point spacing: the spread is an upper bound on the sensor's
// noise; compare classes and half-windows to bound it (docs/range-noise.md).
#include <functional>
#include <string>
#include <vector>

#include "pgm/projection.h"

namespace lidarsim::qualify {

// The classes whose surfaces are locally flat at the scale of a few centimetres.
std::vector<int> planar_classes();  // road, parking, sidewalk, other_ground, building, fence

struct RangeFitOptions {
  // Neighbours on each side in the row. 1 by default: at range a wider window spans more of the
  // surface and reads its shape as noise (on KITTI roads at 45 m: 2.4 cm with 1, 3.1 cm with 2).
  int half_window = 1;
  double gap_factor = 2.5;            // a step wider than this x the row's median step breaks a neighbourhood
  double max_neighbour_rms = 0.15;    // m: the neighbours' own line fit, above this = an edge or clutter
  double max_abs_residual = 1.0;      // m: beyond = another surface
  double min_range = 2.0;             // m: the car's own body and the nearest clutter
  std::vector<int> classes = planar_classes();
};

// One measured range residual (m) with what it may depend on.
struct RangeResidual {
  float range = 0;      // m
  float residual = 0;   // along the beam, scaled by 1 / sqrt(1 + h)
  float incidence = 0;  // rad (NaN when not known)
  float intensity = 0;
  int class_id = 0;
  int material = 0;     // the point's material id (pgm::material)
  int row = 0;          // beam row (laser)
  float azimuth_deg = 0;  // atan2(y, x) in [0, 360): the PGM's column convention (0 straight ahead, growing left)
};

// Residuals of every accepted neighbourhood. rows: the beam row of each point (-1 = skip);
// incidence: per point (rad) or empty.
std::vector<RangeResidual> range_residuals(const std::vector<pgm::Point>& points, const std::vector<int>& rows,
                                           const std::vector<float>& incidence, const RangeFitOptions& options = {});

// The same for a recorded scan: rows and incidence from its projection onto `layout` (pgm::project,
// RowMode::Auto: the ring, else the firing order, else the nearest elevation; incidence from the
// neighbouring cells). `source` names the scan in errors.
std::vector<RangeResidual> scan_range_residuals(const std::vector<pgm::Point>& points, const pgm::BeamLayout& layout,
                                                const RangeFitOptions& options = {}, const std::string& source = "scan");

// 1.4826 x the median absolute deviation from the median (the standard deviation for a Gaussian).
double robust_sigma(std::vector<float> values);

struct SpreadBin {
  double lo = 0, hi = 0;  // the bin's bounds in the binned quantity
  double mean = 0;        // the binned quantity's mean over the bin's residuals
  std::size_t n = 0;
  double sigma = 0;    // 1.4826 MAD, m
  double median = 0;   // m
  double tail3 = 0;    // share beyond 3 sigma (a Gaussian has 0.0027)
};

// Spread per bin [edges[i], edges[i+1]) of key(residual); bins with fewer than min_count residuals
// are left out.
std::vector<SpreadBin> spread_by(const std::vector<RangeResidual>& residuals,
                                 const std::function<double(const RangeResidual&)>& key,
                                 const std::vector<double>& edges, std::size_t min_count = 50);

// Equal-count edges of key over the residuals (count bins), for a quantity of unknown scale.
std::vector<double> quantile_edges(const std::vector<RangeResidual>& residuals,
                                   const std::function<double(const RangeResidual&)>& key, int count);

// sigma(r)^2 = a^2 + (b r)^2 fitted to the bins at their mean range (weighted least squares on sigma^2, weights
// n / sigma^4, the inverse variance of a sample variance); a, b >= 0.
struct SigmaFit {
  double a = 0, b = 0;
};
SigmaFit fit_sigma_of_range(const std::vector<SpreadBin>& range_bins);

}  // namespace lidarsim::qualify
