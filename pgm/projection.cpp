#include "pgm/projection.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

#include "common/angles.h"
#include "common/error.h"

namespace lidarsim::pgm {
namespace {

double azimuth(double x, double y) {
  double az = std::atan2(y, x);
  return az < 0 ? az + kTwoPi : az;
}
void incidence_from_points(PolarGridMap& pgm, const std::vector<float>& xyz);
}  // namespace

std::string to_string(RowMode mode) {
  switch (mode) {
    case RowMode::Auto: return "auto";
    case RowMode::FiringOrder: return "firing_order";
    case RowMode::NearestElevation: return "nearest_elevation";
    case RowMode::Ring: return "ring";
  }
  return "?";
}

int firing_order_rows(const std::vector<Point>& points, std::vector<int>& rows) {
  rows.assign(points.size(), 0);
  if (points.empty()) return 0;
  int row = 0;
  double reference = azimuth(points[0].x, points[0].y);  // last regular azimuth of this row
  for (std::size_t i = 1; i < points.size(); ++i) {
    const double az = azimuth(points[i].x, points[i].y);
    if (reference - az > kPi) {  // wrapped past straight ahead: the next ring begins
      ++row;
      reference = az;
    } else if (az - reference > kPi) {
      // Straggler from just before the wrap: keep it in this row, do not move the reference.
    } else {
      reference = az;
    }
    rows[i] = row;
  }
  return row + 1;
}

namespace {

void check_finite(const std::vector<Point>& points, const std::string& source) {
  for (std::size_t i = 0; i < points.size(); ++i) {
    const Point& p = points[i];
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z) || !std::isfinite(p.intensity))
      throw input_error(source, "point " + std::to_string(i),
                        "non-finite coordinate or intensity (x, y, z, intensity must be finite numbers)");
  }
}

// The base channels, then each requested effect channel once.
std::vector<std::string> projection_channels(const ProjectOptions& options) {
  std::vector<std::string> channels = kBaseChannels;
  for (const auto& name : options.extra_channels) {
    if (std::find(kEffectChannels.begin(), kEffectChannels.end(), name) == kEffectChannels.end())
      throw Error("projection: channel '" + name + "': unknown effect channel");
    if (std::find(channels.begin(), channels.end(), name) == channels.end()) channels.push_back(name);
  }
  return channels;
}

// The row of every point by the requested mode; Auto resolves to the first that applies: the
// points' rings, the firing-order cut when it finds the layout's row count, nearest elevation.
void assign_rows(const std::vector<Point>& points, const BeamLayout& layout, RowMode mode, const std::string& source,
                 std::vector<int>& rows, ProjectionResult& result) {
  const int n_rows = layout.rows();
  const bool all_rings = !points.empty() && std::all_of(points.begin(), points.end(), [&](const Point& p) {
    return p.ring >= 0 && p.ring < n_rows;
  });
  if (mode == RowMode::Auto && all_rings) mode = RowMode::Ring;
  if (mode == RowMode::Auto || mode == RowMode::FiringOrder) {
    result.firing_order_rows = firing_order_rows(points, rows);
    if (result.firing_order_rows == n_rows) {
      mode = RowMode::FiringOrder;
    } else if (mode == RowMode::FiringOrder) {
      throw input_error(source, "rows", "firing-order cut found " + std::to_string(result.firing_order_rows) +
                                            " rows where the beam layout has " + std::to_string(n_rows) +
                                            " (not in firing order, or rings missing)");
    } else {
      mode = RowMode::NearestElevation;
    }
  }
  if (mode == RowMode::Ring) {
    rows.resize(points.size());
    for (std::size_t i = 0; i < points.size(); ++i) {
      if (points[i].ring < 0 || points[i].ring >= n_rows)
        throw input_error(source, "point " + std::to_string(i) + " ring",
                          "must be in 0.." + std::to_string(n_rows - 1) + ", got " + std::to_string(points[i].ring));
      rows[i] = points[i].ring;
    }
  } else if (mode == RowMode::NearestElevation) {
    rows.resize(points.size());
    for (std::size_t i = 0; i < points.size(); ++i) {
      const Point& p = points[i];
      rows[i] = layout.nearest_row(std::atan2(static_cast<double>(p.z), std::hypot(double(p.x), double(p.y))));
    }
  }
  result.row_mode = mode;
}

// The nearest return of each cell wins it: its range goes into `best`, its index into the map's
// point index.
void keep_nearest_returns(const std::vector<Point>& points, const std::vector<int>& rows, const BeamLayout& layout,
                          float min_range, std::vector<float>& best, ProjectionResult& result) {
  PolarGridMap& pgm = result.pgm;
  best.assign(pgm.cells(), std::numeric_limits<float>::infinity());
  auto& index = pgm.point_index();
  result.point_cell.assign(points.size(), -1);
  for (std::size_t i = 0; i < points.size(); ++i) {
    const Point& p = points[i];
    const float r = std::sqrt(p.x * p.x + p.y * p.y + p.z * p.z);
    if (rows[i] < 0 || r < min_range || r == 0.f) {
      ++result.dropped;
      continue;
    }
    const std::int64_t cell = static_cast<std::int64_t>(rows[i]) * layout.columns + layout.column_of(p.x, p.y);
    result.point_cell[i] = cell;
    if (r < best[cell]) {
      best[cell] = r;
      index[cell] = static_cast<std::int64_t>(i);
    }
  }
}

// Every per-point channel from the cell's winning point; the neighbourhood channels (incidence,
// depth_discontinuity) are left for their own passes.
void fill_point_channels(const std::vector<Point>& points, const std::vector<float>& best, PolarGridMap& pgm) {
  enum Kind { Range, Class, Material, Intensity, Mask, Elevation, Azimuth, Height, X, Y, Z, Skip };
  std::vector<std::pair<int, int>> want;  // (channel index, kind)
  const auto& channels = pgm.channel_names();
  for (int c = 0; c < static_cast<int>(channels.size()); ++c) {
    const std::string& n = channels[c];
    const int kind = n == "range"       ? Range
                     : n == "class"     ? Class
                     : n == "material"  ? Material
                     : n == "intensity" ? Intensity
                     : n == "mask"      ? Mask
                     : n == "elevation" ? Elevation
                     : n == "azimuth"   ? Azimuth
                     : n == "height"    ? Height
                     : n == "x"         ? X
                     : n == "y"         ? Y
                     : n == "z"         ? Z
                                        : Skip;
    want.emplace_back(c, kind);
  }
  const auto& index = pgm.point_index();
  for (std::size_t cell = 0; cell < pgm.cells(); ++cell) {
    if (index[cell] < 0) continue;
    const Point& p = points[static_cast<std::size_t>(index[cell])];
    for (auto [c, kind] : want) {
      float v = 0;
      switch (kind) {
        case Range: v = best[cell]; break;
        case Class: v = static_cast<float>(p.class_id); break;
        case Material: v = static_cast<float>(p.material_id); break;
        case Intensity: v = p.intensity; break;
        case Mask: v = 1.f; break;
        case Elevation: v = static_cast<float>(std::atan2(double(p.z), std::hypot(double(p.x), double(p.y)))); break;
        case Azimuth: v = static_cast<float>(azimuth(p.x, p.y)); break;
        case Height: case Z: v = p.z; break;
        case X: v = p.x; break;
        case Y: v = p.y; break;
        default: continue;
      }
      pgm.channel(c)[cell] = v;
    }
  }
}

// From the measured points, not the nominal beam directions: KITTI's rows wander by ~0.5 deg.
void fill_incidence_from_winners(const std::vector<Point>& points, PolarGridMap& pgm) {
  const std::size_t cells = pgm.cells();
  const auto& index = pgm.point_index();
  std::vector<float> xyz(3 * cells, 0.f);
  for (std::size_t cell = 0; cell < cells; ++cell) {
    if (index[cell] < 0) continue;
    const Point& p = points[static_cast<std::size_t>(index[cell])];
    xyz[cell] = p.x, xyz[cells + cell] = p.y, xyz[2 * cells + cell] = p.z;
  }
  incidence_from_points(pgm, xyz);
}

}  // namespace

ProjectionResult project(const std::vector<Point>& points, const BeamLayout& layout, const ProjectOptions& options,
                         const std::string& source) {
  check_finite(points, source);
  ProjectionResult result;
  result.pgm = PolarGridMap(layout, projection_channels(options));
  std::vector<int> rows;
  assign_rows(points, layout, options.row_mode, source, rows, result);
  std::vector<float> best;
  keep_nearest_returns(points, rows, layout, options.min_range, best, result);
  fill_point_channels(points, best, result.pgm);
  if (result.pgm.has_channel("incidence")) fill_incidence_from_winners(points, result.pgm);
  if (result.pgm.has_channel("depth_discontinuity")) compute_depth_discontinuity(result.pgm);
  return result;
}

namespace {

// Incidence per cell from the 3D points of the cell and its neighbours (`xyz` [3, H, W], valid
// where range > 0).
void incidence_from_points(PolarGridMap& pgm, const std::vector<float>& xyz) {
  const int H = pgm.rows(), W = pgm.cols();
  const std::size_t plane = pgm.cells();
  const float* range = pgm.channel("range");
  float* out = pgm.channel("incidence");
  auto valid = [&](int r, int c) { return r >= 0 && r < H && range[static_cast<std::size_t>(r) * W + c] > 0.f; };
  auto point_of = [&](int r, int c, double p[3]) {
    const std::size_t i = static_cast<std::size_t>(r) * W + c;
    for (int k = 0; k < 3; ++k) p[k] = xyz[k * plane + i];
  };
  // Rows are independent: split them over the threads (a simulated frame pays this every time).
#pragma omp parallel for schedule(static)
  for (int r = 0; r < H; ++r) {
    for (int c = 0; c < W; ++c) {
      const std::size_t cell = static_cast<std::size_t>(r) * W + c;
      out[cell] = 0.f;
      if (!(range[cell] > 0.f)) continue;
      // Tangent vectors from neighbours (columns wrap around 360 deg); central difference when
      // both neighbours have returns, one-sided otherwise.
      double p0[3], a[3], b[3];
      point_of(r, c, p0);
      auto tangent = [&](int r1, int c1, int r2, int c2, double t[3]) {
        const bool v1 = valid(r1, c1), v2 = valid(r2, c2);
        if (!v1 && !v2) return false;
        double q1[3], q2[3];
        if (v1) point_of(r1, c1, q1); else std::copy(p0, p0 + 3, q1);
        if (v2) point_of(r2, c2, q2); else std::copy(p0, p0 + 3, q2);
        for (int k = 0; k < 3; ++k) t[k] = q2[k] - q1[k];
        return true;
      };
      if (!tangent(r, (c + W - 1) % W, r, (c + 1) % W, a) || !tangent(r - 1, c, r + 1, c, b)) continue;
      const double n[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
      const double nn = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
      const double pn = std::sqrt(p0[0] * p0[0] + p0[1] * p0[1] + p0[2] * p0[2]);
      if (nn <= 0 || pn <= 0) continue;
      const double cosine = std::abs(n[0] * p0[0] + n[1] * p0[1] + n[2] * p0[2]) / (nn * pn);
      out[cell] = static_cast<float>(std::acos(std::min(1.0, cosine)));
    }
  }
}

}  // namespace

void compute_incidence(PolarGridMap& pgm) {
  if (!pgm.has_channel("incidence")) pgm.add_channel("incidence");
  const BeamLayout& layout = pgm.layout();
  const int H = pgm.rows(), W = pgm.cols();
  const std::size_t plane = pgm.cells();
  const float* range = pgm.channel("range");
  // Points from the cell's range along the row's elevation and the column's centre azimuth; the
  // sines and cosines once per row and column (this runs on every simulated frame).
  std::vector<double> cos_az(W), sin_az(W);
  for (int c = 0; c < W; ++c) cos_az[c] = std::cos(layout.azimuth_of_column(c)), sin_az[c] = std::sin(layout.azimuth_of_column(c));
  std::vector<float> xyz(3 * plane, 0.f);
  for (int r = 0; r < H; ++r) {
    const double cos_el = std::cos(layout.elevations_rad[r]), sin_el = std::sin(layout.elevations_rad[r]);
    for (int c = 0; c < W; ++c) {
      const std::size_t i = static_cast<std::size_t>(r) * W + c;
      const double rg = range[i];
      xyz[i] = static_cast<float>(rg * cos_el * cos_az[c]);
      xyz[plane + i] = static_cast<float>(rg * cos_el * sin_az[c]);
      xyz[2 * plane + i] = static_cast<float>(rg * sin_el);
    }
  }
  incidence_from_points(pgm, xyz);
}

void compute_depth_discontinuity(PolarGridMap& pgm) {
  if (!pgm.has_channel("depth_discontinuity")) pgm.add_channel("depth_discontinuity");
  const int H = pgm.rows(), W = pgm.cols();
  const float* range = pgm.channel("range");
  float* out = pgm.channel("depth_discontinuity");
  for (int r = 0; r < H; ++r)
    for (int c = 0; c < W; ++c) {
      const float* row = range + static_cast<std::size_t>(r) * W;
      const float here = row[c];
      float edge = 0.f;
      if (here > 0.f)
        for (int q : {(c + W - 1) % W, (c + 1) % W})
          if (row[q] > 0.f && std::abs(row[q] - here) > 0.1f * std::max(here, 1e-3f)) edge = 1.f;
      out[static_cast<std::size_t>(r) * W + c] = edge;
    }
}

std::vector<float> back_project(const float* plane, const std::vector<std::int64_t>& point_cell) {
  std::vector<float> out(point_cell.size(), std::numeric_limits<float>::quiet_NaN());
  for (std::size_t i = 0; i < point_cell.size(); ++i)
    if (point_cell[i] >= 0) out[i] = plane[point_cell[i]];
  return out;
}

}  // namespace lidarsim::pgm
