#include "data/reference_sensor.h"

#include <Eigen/Core>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <numbers>
#include <random>
#include <vector>

#include "common/angles.h"
#include "common/atomic_file.h"
#include "common/error.h"
#include "pgm/beam_layout.h"
#include "sensor/kpi_model.h"

namespace fs = std::filesystem;

namespace lidarsim::data {

namespace {



std::string seq_name(int s, int width) {
  char buf[16];
  std::snprintf(buf, sizeof buf, "%0*d", width, s);
  return buf;
}

struct Track {
  int id = 0, start = 0, end = 0;
  std::string type;
  Eigen::Vector3d p0, v, size;
  double heading = 0, truncated = 0;
  int occluded = 0;
};

}  // namespace

std::string to_string(ObjectEffect e) {
  switch (e) {
    case ObjectEffect::VelocityLag: return "velocity_lag";
    case ObjectEffect::TruncationSize: return "truncation_size";
    case ObjectEffect::AspectAcross: return "aspect_across";
    case ObjectEffect::AzimuthDropout: return "azimuth_dropout";
    case ObjectEffect::AzimuthWindowDropout: return "azimuth_window_dropout";
    case ObjectEffect::AspectSpread: return "aspect_spread";
    case ObjectEffect::FalsePositiveHotspot: return "fp_hotspot";
    case ObjectEffect::OcclusionSize: return "occlusion_size";
    default: return "none";
  }
}
std::string to_string(IntensityEffect e) {
  switch (e) {
    case IntensityEffect::Incidence: return "incidence";
    case IntensityEffect::Height: return "height";
    case IntensityEffect::Azimuth: return "azimuth";
    case IntensityEffect::BeamGain: return "beam_gain";
    case IntensityEffect::AzimuthWindow: return "azimuth_window";
    default: return "none";
  }
}
std::string effect_feature(ObjectEffect e) {
  switch (e) {
    case ObjectEffect::VelocityLag: return "radial_velocity";
    case ObjectEffect::TruncationSize: return "truncation";
    case ObjectEffect::AspectAcross: return "heading_to_line_of_sight";
    case ObjectEffect::AzimuthDropout: return "azimuth";
    case ObjectEffect::AzimuthWindowDropout: return "azimuth";
    case ObjectEffect::AspectSpread: return "heading_to_line_of_sight";
    case ObjectEffect::FalsePositiveHotspot: return "azimuth";
    case ObjectEffect::OcclusionSize: return "occlusion";
    default: return "";
  }
}
std::string effect_feature(IntensityEffect e) {
  switch (e) {
    case IntensityEffect::Incidence: return "incidence_angle";
    case IntensityEffect::Height: return "height";
    case IntensityEffect::Azimuth: return "azimuth";
    case IntensityEffect::BeamGain: return "beam_row";
    case IntensityEffect::AzimuthWindow: return "azimuth";
    default: return "";
  }
}

namespace {

// The main random stream of the tracking data: tracks, detections and clutter draw from it in
// this order, so its use must not move.
struct TrackingDraws {
  std::mt19937_64 rng;
  std::normal_distribution<double> N01{0, 1};
  std::uniform_real_distribution<double> U{0, 1};
  explicit TrackingDraws(std::uint64_t seed) : rng(seed) {}
  double u() { return U(rng); }
  double n() { return N01(rng); }
  double uni(double a, double b) { return a + (b - a) * U(rng); }
};

// The tracking data's other streams: each planted false-positive form draws from its own, so
// nothing else moves when it is switched on.
struct FalsePositiveDraws {
  std::mt19937_64 spot_rng, ghost_rng;
  std::vector<std::array<double, 3>> ghosts;  // x, y (sensor frame), score; the live ones of this sequence
};

// Calibration: R0_rect = I, Tr_velo_to_cam = the axis permutation (cam x = -y, y = -z, z = x).
void write_tracking_calib(const fs::path& file) {
  write_file_atomically(file,
                        "P0: 700 0 600 0 0 700 170 0 0 0 1 0\nP1: 700 0 600 0 0 700 170 0 0 0 1 0\n"
                        "P2: 700 0 600 0 0 700 170 0 0 0 1 0\nP3: 700 0 600 0 0 700 170 0 0 0 1 0\n"
                        "R0_rect: 1 0 0 0 1 0 0 0 1\nTr_velo_to_cam: 0 -1 0 0 0 0 -1 0 1 0 0 0\n"
                        "Tr_imu_to_velo: 1 0 0 0 0 1 0 0 0 0 1 0\n");
}

std::vector<Track> draw_tracks(const ReferenceTrackingOptions& o, TrackingDraws& d) {
  auto uni = [&](double a, double b) { return d.uni(a, b); };
  std::vector<Track> tracks(o.tracks);
  for (int k = 0; k < o.tracks; ++k) {
    Track& t = tracks[k];
    t.id = k;
    const double u = d.u();
    t.type = u < 0.7 ? "Car" : u < 0.85 ? "Pedestrian" : "Cyclist";
    const double vmax = t.type == "Car" ? 12 : t.type == "Cyclist" ? 5 : 1.5;
    t.size = t.type == "Car" ? Eigen::Vector3d(uni(3.6, 4.8), uni(1.6, 1.9), uni(1.4, 1.7))
             : t.type == "Cyclist" ? Eigen::Vector3d(uni(1.6, 1.9), uni(0.5, 0.7), uni(1.6, 1.8))
                                   : Eigen::Vector3d(uni(0.5, 0.9), uni(0.5, 0.7), uni(1.6, 1.9));
    t.start = static_cast<int>(uni(0, o.frames * 0.5));
    t.end = std::min(o.frames, t.start + static_cast<int>(uni(o.frames * 0.3, o.frames * 0.8)));
    const double dur = (t.end - t.start) * 0.1;
    t.v = Eigen::Vector3d(uni(-vmax, vmax), uni(-0.3, 0.3) * vmax, 0);
    // Start so the whole track stays between 5 and 60 m ahead.
    const double x_end_lo = 5 - t.v.x() * dur, x_end_hi = 60 - t.v.x() * dur;
    const double x0 = uni(std::max(5.0, x_end_lo), std::max(std::max(5.0, x_end_lo) + 1, std::min(60.0, x_end_hi)));
    t.p0 = Eigen::Vector3d(x0, uni(-15, 15), -1.73 + t.size.z() / 2);
    t.heading = t.v.head<2>().norm() > 0.5 ? std::atan2(t.v.y(), t.v.x()) : uni(-kPi, kPi);
    t.truncated = uni(0, 0.8);
    t.occluded = static_cast<int>(uni(0, 2.999));
  }
  return tracks;
}

// The planted error effects on one detection of track t at bird's-eye position bev (u: the line
// of sight, left: across it): along/across offsets and the size changed in place.
void plant_error_effects(const ReferenceTrackingOptions& o, const Track& t, const Eigen::Vector2d& bev,
                         const Eigen::Vector2d& u, const Eigen::Vector2d& left, double& along, double& across,
                         Eigen::Vector3d& sz) {
  for (const ObjectEffect effect : {o.effect, o.second_effect}) {
    switch (effect) {
    case ObjectEffect::VelocityLag: {
      const Eigen::Vector2d lag = -0.08 * t.v.head<2>();
      along += lag.dot(u);
      across += lag.dot(left);
      break;
    }
    case ObjectEffect::TruncationSize: sz.x() -= 0.45 * t.truncated * t.size.x(); break;
    case ObjectEffect::OcclusionSize: sz.x() -= kOcclusionSizeShare * t.occluded * t.size.x(); break;
    case ObjectEffect::AspectAcross: {
      double rel = std::abs(wrap_angle_fmod(t.heading - std::atan2(bev.y(), bev.x())));
      if (rel > kPi / 2) rel = kPi - rel;
      across += 1.2 * (rel / (kPi / 2)) - 0.6;
      break;
    }
    case ObjectEffect::AspectSpread: {
      double rel = std::abs(wrap_angle_fmod(t.heading - std::atan2(bev.y(), bev.x())));
      if (rel > kPi / 2) rel = kPi - rel;
      across *= kSpreadBase + kSpreadPerAspect * rel / (kPi / 2);
      break;
    }
    case ObjectEffect::AzimuthDropout:
    case ObjectEffect::AzimuthWindowDropout:
    case ObjectEffect::FalsePositiveHotspot:
    case ObjectEffect::None: break;
    }
  }
}

// Track t's label line in frame f, and (if drawn detected) its detection line in dets[class].
void append_track_frame(const ReferenceTrackingOptions& o, const Track& t, int f, TrackingDraws& d,
                        std::string& labels, std::string dets[sensor::kModelledClassCount]) {
  char line[512];
  const Eigen::Vector3d c = t.p0 + t.v * ((f - t.start) * 0.1);
  const double ry = std::atan2(-std::cos(t.heading), -std::sin(t.heading));
  // Rectified camera: (-y, -z + h/2, x) is the bottom centre.
  std::snprintf(line, sizeof line, "%d %d %s %.4f %d -10 0 0 100 100 %.4f %.4f %.4f %.4f %.4f %.4f %.5f\n", f,
                t.id, t.type.c_str(), t.truncated, t.occluded, t.size.z(), t.size.y(), t.size.x(), -c.y(),
                -c.z() + t.size.z() / 2, c.x(), ry);
  labels += line;
  // The same draw for every effect, so the other effects' outputs stay as they were.
  double pd = o.detection_probability;
  auto planted = [&](ObjectEffect e) { return o.effect == e || o.second_effect == e; };
  if (planted(ObjectEffect::AzimuthDropout)) {
    const double az = std::atan2(c.y(), c.x());
    if (az >= kDropoutAzimuthLo && az <= kDropoutAzimuthHi) pd *= kDropoutFactor;
  }
  if (planted(ObjectEffect::AzimuthWindowDropout)) {
    const double az = std::atan2(c.y(), c.x());
    if (az >= o.window_azimuth_lo && az <= o.window_azimuth_hi) pd *= kDropoutFactor;
  }
  if (d.u() > pd) return;
  const Eigen::Vector2d bev = c.head<2>();
  const Eigen::Vector2d u = bev / bev.norm(), left(-u.y(), u.x());
  double along = o.noise * d.n(), across = o.noise * d.n();
  Eigen::Vector3d sz = t.size + Eigen::Vector3d(d.n(), d.n(), d.n()) * (o.noise / 2);
  double heading = t.heading + o.noise / 5 * d.n();
  plant_error_effects(o, t, bev, u, left, along, across, sz);
  const Eigen::Vector2d pos = bev + along * u + across * left;
  const double dry = std::atan2(-std::cos(heading), -std::sin(heading));
  const int cls = t.type == "Car" ? 0 : t.type == "Pedestrian" ? 1 : 2;
  const int type_id = cls == 0 ? 2 : cls == 1 ? 1 : 3;
  std::snprintf(line, sizeof line, "%d,%d,0,0,100,100,%.3f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.5f,-10\n", f, type_id,
                d.uni(3, 12), sz.z(), sz.y(), sz.x(), -pos.y(), -c.z() + sz.z() / 2, pos.x(), dry);
  dets[cls] += line;
}

// A car-sized false positive at sensor-frame (x, y) in frame f, as a detection line.
void append_false_car(std::string& dets, int f, double score, double x, double y) {
  char line[512];
  std::snprintf(line, sizeof line, "%d,2,0,0,100,100,%.3f,1.5,1.7,4.0,%.4f,%.4f,%.4f,0,-10\n", f, score, -y,
                1.73 - 0.75, x);
  dets += line;
}

// Frame f's false positives: clutter (Bernoulli per slot), persistent ghosts and the hot spot.
void append_false_positives(const ReferenceTrackingOptions& o, bool hotspot, int f, TrackingDraws& d,
                            FalsePositiveDraws& fp, std::string& dets) {
  for (int k = 0; k < 3; ++k)
    if (d.u() < o.false_positives / 3) {
      if (!o.polar_clutter) {
        char line[512];
        std::snprintf(line, sizeof line, "%d,2,0,0,100,100,%.3f,1.5,1.7,4.0,%.4f,%.4f,%.4f,0,-10\n", f,
                      d.uni(0.5, 4), d.uni(-20, 20), 1.73 - 0.75, d.uni(5, 60));
        dets += line;
      } else {
        const double score = d.uni(0.5, 4), az = d.uni(-kPi / 4, kPi / 4), r = d.uni(5, 60);
        append_false_car(dets, f, score, r * std::cos(az), r * std::sin(az));
      }
    }
  if (o.ghost_survival > 0) {
    // Survivors first, then births at the rate that keeps kFpGhostRate per frame (the first frame
    // starts with the stationary count).
    std::uniform_real_distribution<double> gu(0, 1);
    std::normal_distribution<double> gn(0, kFpGhostJitter);
    auto& ghosts = fp.ghosts;
    size_t kept = 0;
    for (auto& g : ghosts)
      if (gu(fp.ghost_rng) < o.ghost_survival) g[0] += gn(fp.ghost_rng), g[1] += gn(fp.ghost_rng), ghosts[kept++] = g;
    ghosts.resize(kept);
    const int n = std::poisson_distribution<int>(kFpGhostRate * (f == 0 ? 1 : 1 - o.ghost_survival))(fp.ghost_rng);
    for (int k = 0; k < n; ++k) {
      const double az = -kPi / 4 + kPi / 2 * gu(fp.ghost_rng), r = 5 + 55 * gu(fp.ghost_rng);
      ghosts.push_back({r * std::cos(az), r * std::sin(az), 0.5 + 3.5 * gu(fp.ghost_rng)});
    }
    for (const auto& g : ghosts) append_false_car(dets, f, g[2], g[0], g[1]);
  }
  if (hotspot) {
    std::uniform_real_distribution<double> su(0, 1);
    const int n = std::poisson_distribution<int>(kFpHotspotRate)(fp.spot_rng);
    for (int k = 0; k < n; ++k) {
      const double az = kFpHotspotAzimuthLo + (kFpHotspotAzimuthHi - kFpHotspotAzimuthLo) * su(fp.spot_rng);
      const double r = kFpHotspotRangeLo + (kFpHotspotRangeHi - kFpHotspotRangeLo) * su(fp.spot_rng);
      const double score = 0.5 + 3.5 * su(fp.spot_rng);
      append_false_car(dets, f, score, r * std::cos(az), r * std::sin(az));
    }
  }
}

// One sequence's calibration, labels and the three classes' detection files.
void write_tracking_sequence(const fs::path& dir, const std::string& name, const ReferenceTrackingOptions& o,
                             bool hotspot, TrackingDraws& d, FalsePositiveDraws& fp) {
  write_tracking_calib(dir / "calib" / (name + ".txt"));
  const std::vector<Track> tracks = draw_tracks(o, d);
  std::string labels;
  std::string dets[sensor::kModelledClassCount];  // indexed like sensor::kModelledClasses
  fp.ghosts.clear();
  for (int f = 0; f < o.frames; ++f) {
    for (const Track& t : tracks)
      if (f >= t.start && f < t.end) append_track_frame(o, t, f, d, labels, dets);
    append_false_positives(o, hotspot, f, d, fp, dets[0]);
  }
  // A DontCare region in the last frame, as KITTI's label files have: the reader takes the last
  // labelled frame as the sequence's end, and clutter may fall into frames after the last track.
  char line[512];
  std::snprintf(line, sizeof line, "%d -1 DontCare -1 -1 -10 0 0 100 100 -1 -1 -1 -1000 -1000 -1000 -10\n",
                o.frames - 1);
  labels += line;
  write_file_atomically(dir / "label_02" / (name + ".txt"), labels);
  for (int k = 0; k < sensor::kModelledClassCount; ++k)
    write_file_atomically(dir / "detection" / ("pointrcnn_" + sensor::kModelledClasses[k] + "_val") / (name + ".txt"),
                          dets[k]);
}

}  // namespace

void write_reference_tracking(const fs::path& dir, const ReferenceTrackingOptions& o) {
  if (o.sequences < 1 || o.frames < 2 || o.tracks < 1) throw Error("reference sensor: sequences, frames, tracks >= 1");
  for (const char* sub : {"label_02", "calib", "detection/pointrcnn_Car_val", "detection/pointrcnn_Pedestrian_val",
                          "detection/pointrcnn_Cyclist_val"})
    fs::create_directories(dir / sub);
  TrackingDraws d(o.seed);
  // The hot spot's false positives and the ghosts: streams of their own, so nothing else moves.
  FalsePositiveDraws fp{std::mt19937_64(o.seed ^ 0x5a17c0ffee5eedULL), std::mt19937_64(o.seed ^ 0x6b05757acce55ULL),
                        {}};
  const bool hotspot = o.effect == ObjectEffect::FalsePositiveHotspot || o.second_effect == ObjectEffect::FalsePositiveHotspot;
  std::string seqmap;
  for (int s = 0; s < o.sequences; ++s) {
    const std::string name = seq_name(s, 4);
    seqmap += name + " empty 000000 " + seq_name(o.frames, 6) + "\n";
    write_tracking_sequence(dir, name, o, hotspot, d, fp);
  }
  write_file_atomically(dir / "evaluate_tracking.seqmap.val", seqmap);
}

double reference_beam_gain(int row, double spread) {
  // A fixed pseudo-random u in [-1, 1) per laser (splitmix64 of the row).
  std::uint64_t x = static_cast<std::uint64_t>(row) + 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  x ^= x >> 31;
  const double u = static_cast<double>(x >> 11) * 0x1.0p-53 * 2 - 1;
  return 1 + spread * u;
}

namespace {

// A ring of wall facets at random distances (vertices), so facet normals vary irregularly; each
// facet has a kind (building, fence, vegetation).
struct WallRing {
  static constexpr int kFacets = 40;
  std::vector<Eigen::Vector2d> vertex;
  std::vector<int> kind;
};

WallRing random_wall_ring(std::mt19937_64& rng) {
  std::uniform_real_distribution<double> U(0, 1);
  WallRing w;
  const int K = WallRing::kFacets;
  w.vertex.resize(K);
  w.kind.resize(K);
  for (int k = 0; k < K; ++k) {
    const double a = 2 * kPi * (k + 0.3 * (U(rng) - 0.5)) / K - kPi, r = 10 + 20 * U(rng);
    w.vertex[k] = Eigen::Vector2d(r * std::cos(a), r * std::sin(a));
    w.kind[k] = static_cast<int>(U(rng) * 2.999);
  }
  return w;
}

struct FacetHit {
  double distance = 1e9;  // horizontal, along the ray; 1e9: no facet
  Eigen::Vector2d normal{1, 0};
  int facet = 0;
};

// The nearest facet the horizontal ray direction `d` meets.
FacetHit nearest_facet(const WallRing& w, const Eigen::Vector2d& d) {
  FacetHit h;
  const int K = WallRing::kFacets;
  for (int k = 0; k < K; ++k) {
    const Eigen::Vector2d a = w.vertex[k], b = w.vertex[(k + 1) % K], e = b - a;
    const double den = d.x() * e.y() - d.y() * e.x();
    if (std::abs(den) < 1e-12) continue;
    const double t = (a.x() * e.y() - a.y() * e.x()) / den;  // along the ray
    const double u = (a.x() * d.y() - a.y() * d.x()) / den;  // along the facet
    if (t > 0 && u >= 0 && u <= 1 && t < h.distance)
      h.distance = t, h.facet = k, h.normal = Eigen::Vector2d(e.y(), -e.x()).normalized();
  }
  return h;
}

double planted_gain(const ReferenceScanOptions& o, int row, double az, double z_above_ground, double incidence) {
  switch (o.effect) {
    case IntensityEffect::Incidence: return std::cos(incidence);
    case IntensityEffect::Height: return 0.6 + 0.3 * z_above_ground;
    case IntensityEffect::Azimuth: return 1 + 0.5 * std::sin(az);
    case IntensityEffect::BeamGain: return reference_beam_gain(row, o.beam_gain_spread);
    case IntensityEffect::AzimuthWindow: return az >= o.window_azimuth_lo && az <= o.window_azimuth_hi ? o.window_gain : 1.0;
    case IntensityEffect::None: break;
  }
  return 1;
}

}  // namespace

void write_reference_semantickitti(const fs::path& dir, const ReferenceScanOptions& o) {
  if (o.scans < 1 || o.columns < 16) throw Error("reference sensor: scans >= 1, columns >= 16");
  const fs::path seq = dir / "sequences" / "00";
  fs::create_directories(seq / "velodyne");
  fs::create_directories(seq / "labels");
  const pgm::BeamLayout layout = pgm::BeamLayout::hdl64e(o.columns);
  const double sensor_h = 1.73, wall_top = 4.0;
  std::mt19937_64 rng(o.seed);
  std::normal_distribution<double> N01(0, 1);
  // SemanticKITTI labels and albedo: road, sidewalk, building, fence, vegetation.
  const std::uint32_t lab_road = 40, lab_sidewalk = 48;
  const std::uint32_t wall_labels[3] = {50, 51, 70};
  const double wall_albedo[3] = {0.35, 0.45, 0.55};
  for (int s = 0; s < o.scans; ++s) {
    const WallRing walls = random_wall_ring(rng);
    std::vector<float> pts;
    std::vector<std::uint32_t> labels;
    for (int row = 0; row < layout.rows(); ++row) {
      const double el = layout.elevations_rad[row];
      for (int col = 0; col < o.columns; ++col) {
        const double az = -kPi + (col + 0.5) * 2 * kPi / o.columns;
        const Eigen::Vector2d d(std::cos(az), std::sin(az));
        const FacetHit wall = nearest_facet(walls, d);
        const double tg = el < 0 ? sensor_h / std::tan(-el) : 1e9;  // ground hit, horizontal distance
        double range = 0, albedo = 0, incidence = 0, z = 0;
        std::uint32_t label = 0;
        if (tg < wall.distance) {
          range = tg / std::cos(el);
          z = -sensor_h;
          const bool sidewalk = tg > wall.distance - 2.5;
          label = sidewalk ? lab_sidewalk : lab_road;
          albedo = sidewalk ? 0.30 : 0.20;
          incidence = kPi / 2 - std::abs(el);
        } else {
          z = wall.distance * std::tan(el);
          if (wall.distance >= 1e8 || z > wall_top - sensor_h) continue;  // sky: no return
          range = wall.distance / std::cos(el);
          label = wall_labels[walls.kind[wall.facet]];
          albedo = wall_albedo[walls.kind[wall.facet]];
          const Eigen::Vector3d ray(std::cos(el) * d.x(), std::cos(el) * d.y(), std::sin(el));
          incidence = std::acos(std::min(1.0, std::abs(ray.dot(Eigen::Vector3d(wall.normal.x(), wall.normal.y(), 0)))));
        }
        const double gain = planted_gain(o, row, az, z + sensor_h, incidence);
        const double intensity = std::clamp(albedo * gain + o.noise * N01(rng), 0.0, 1.0);
        pts.insert(pts.end(), {float(range * std::cos(el) * d.x()), float(range * std::cos(el) * d.y()),
                               float(range * std::sin(el)), float(intensity)});
        labels.push_back(label);
      }
    }
    const std::string id = seq_name(s, 6);
    write_file_atomically(seq / "velodyne" / (id + ".bin"),
                          std::string(reinterpret_cast<const char*>(pts.data()), pts.size() * sizeof(float)));
    write_file_atomically(seq / "labels" / (id + ".label"),
                          std::string(reinterpret_cast<const char*>(labels.data()), labels.size() * sizeof(std::uint32_t)));
  }
}

}  // namespace lidarsim::data
