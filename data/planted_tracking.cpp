#include "data/planted_tracking.h"

#include <Eigen/Core>
#include <Eigen/LU>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <numbers>
#include <optional>
#include <random>
#include <set>
#include <sstream>

#include "common/angles.h"
#include "common/atomic_file.h"
#include "common/error.h"
#include "data/kitti_tracking.h"

namespace fs = std::filesystem;

namespace lidarsim::data {

namespace {

constexpr double kDt = 0.1;  // KITTI tracking: 10 Hz
constexpr int kClasses = sensor::kModelledClassCount;
const auto& kClassNames = sensor::kModelledClasses;
// A class's typical box (length, width, height; m), for its false positives.
const Eigen::Vector3d kClassBox[kClasses] = {{3.9, 1.6, 1.5}, {0.8, 0.6, 1.7}, {1.7, 0.6, 1.7}};

using TrackingRng = std::mt19937_64;

double uni(TrackingRng& rng, double a, double b) { return a + (b - a) * std::uniform_real_distribution<double>(0, 1)(rng); }
int pick(TrackingRng& rng, int n) { return std::min(n - 1, static_cast<int>(uni(rng, 0, n))); }
double gauss(TrackingRng& rng) { return std::normal_distribution<double>(0, 1)(rng); }

int class_index(const std::string& type) {
  for (int c = 0; c < kClasses; ++c)
    if (type == kClassNames[c]) return c;
  return -1;
}


double quantile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<size_t>(q * static_cast<double>(v.size())))];
}

// One modelled truth object of a window with what the effects depend on (as the loop computes them).
struct Truth {
  const KittiTrackingObject* o = nullptr;
  int cls = 0, frame = 0;          // frame: in the window (written frame number)
  Eigen::Vector2d bev, u, left, v;  // BEV centre, line of sight, its left normal, velocity (m/s)
  double range = 0, azimuth = 0, aspect = 0;  // aspect: heading to the line of sight folded to [0, 1]
};

struct Window {
  PlantedSequence where;
  KittiTrackingSequence seq;
  std::vector<Truth> truth;  // frame by frame
  int tracks = 0;
};

// The window's modelled truth, velocities by central differences within the window (one-sided at a
// track's ends), exactly as the loop's features are computed from the written labels.
void fill_truth(Window& w) {
  std::map<int, std::map<int, Eigen::Vector2d>> track_pos;
  const int end = std::min<int>(w.where.first_frame + w.where.frames, static_cast<int>(w.seq.frames.size()));
  for (int f = w.where.first_frame; f < end; ++f)
    for (const auto& o : w.seq.frames[f].truth)
      if (class_index(o.type) >= 0) track_pos[o.object.id][f - w.where.first_frame] = o.object.position.head<2>();
  w.truth.clear();
  w.tracks = static_cast<int>(track_pos.size());
  for (int f = w.where.first_frame; f < end; ++f)
    for (const auto& o : w.seq.frames[f].truth) {
      const int cls = class_index(o.type);
      if (cls < 0) continue;
      Truth t;
      t.o = &o, t.cls = cls, t.frame = f - w.where.first_frame;
      t.bev = o.object.position.head<2>();
      t.range = std::max(t.bev.norm(), 1e-6);
      t.u = t.bev / t.range, t.left = Eigen::Vector2d(-t.u.y(), t.u.x());
      t.azimuth = std::atan2(t.bev.y(), t.bev.x());
      double rel = std::abs(wrap_angle_fmod(o.object.heading - t.azimuth));
      if (rel > kPi / 2) rel = kPi - rel;
      t.aspect = rel / (kPi / 2);
      const auto& tp = track_pos[o.object.id];
      const auto prev = tp.find(t.frame - 1), next = tp.find(t.frame + 1);
      t.v.setZero();
      if (prev != tp.end() && next != tp.end()) t.v = (next->second - prev->second) / (2 * kDt);
      else if (next != tp.end()) t.v = (next->second - t.bev) / kDt;
      else if (prev != tp.end()) t.v = (t.bev - prev->second) / kDt;
      w.truth.push_back(t);
    }
}

std::vector<std::string> source_sequence_names(const fs::path& source) {
  if (!fs::is_directory(source / "label_02"))
    throw Error("planted tracking: " + (source / "label_02").string() + ": no such folder (the real KITTI tracking ground truth)");
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(source / "label_02"))
    if (e.path().extension() == ".txt" && fs::exists(source / "calib" / e.path().filename()))
      names.push_back(e.path().stem().string());
  std::sort(names.begin(), names.end());
  return names;
}

// k sequences in random order, each with a random window of max_frames frames holding at least
// kPlantedMinTracks modelled tracks (three tries per sequence).
std::vector<Window> choose_windows(const PlantedTrackingOptions& o, TrackingRng& rng) {
  std::vector<std::string> names = source_sequence_names(o.source);
  std::shuffle(names.begin(), names.end(), rng);
  std::vector<Window> out;
  for (const std::string& name : names) {
    if (static_cast<int>(out.size()) == o.sequences) break;
    Window w;
    w.seq = read_kitti_tracking_sequence(o.source, name, "planted_none");  // truth only
    const int len = static_cast<int>(w.seq.frames.size());
    const int frames = o.max_frames > 0 ? std::min(o.max_frames, len) : len;
    for (int attempt = 0; attempt < 3; ++attempt) {
      w.where = {name, pick(rng, len - frames + 1), frames};
      fill_truth(w);
      if (w.tracks >= kPlantedMinTracks) break;
    }
    if (w.tracks >= kPlantedMinTracks) out.push_back(std::move(w));
  }
  if (static_cast<int>(out.size()) < o.sequences)
    throw Error("planted tracking: " + o.source.string() + ": only " + std::to_string(out.size()) +
                " sequences have a window of " + std::to_string(o.max_frames) + " frames with >= " +
                std::to_string(kPlantedMinTracks) + " Car/Pedestrian/Cyclist tracks, " + std::to_string(o.sequences) +
                " asked");
  return out;
}

PlantedBaseModel draw_base(TrackingRng& rng) {
  PlantedBaseModel b;
  // Nominal sigmas per class (Car, Pedestrian, Cyclist), each scaled by its own factor 0.8-1.25.
  const double along[kClasses] = {0.15, 0.12, 0.15}, across[kClasses] = {0.10, 0.08, 0.10},
               length[kClasses] = {0.20, 0.10, 0.15}, width[kClasses] = {0.08, 0.06, 0.06},
               height[kClasses] = {0.08, 0.06, 0.06}, heading[kClasses] = {0.05, 0.15, 0.10},
               detection[kClasses] = {0.92, 0.85, 0.85}, fp[kClasses] = {0.3, 0.15, 0.05};
  for (int c = 0; c < kClasses; ++c) {
    b.along[c] = along[c] * uni(rng, 0.8, 1.25);
    b.across[c] = across[c] * uni(rng, 0.8, 1.25);
    b.length[c] = length[c] * uni(rng, 0.8, 1.25);
    b.width[c] = width[c] * uni(rng, 0.8, 1.25);
    b.height[c] = height[c] * uni(rng, 0.8, 1.25);
    b.heading[c] = heading[c] * uni(rng, 0.8, 1.25);
    b.detection[c] = std::min(0.98, detection[c] * uni(rng, 0.95, 1.05));
    b.fp_rate[c] = fp[c] * uni(rng, 0.7, 1.4);
  }
  b.occlusion_loss = uni(rng, 0.05, 0.2);
  return b;
}

double base_sigma(const PlantedBaseModel& b, const std::string& target, int c) {
  if (target == "position_along") return b.along[c];
  if (target == "position_across") return b.across[c];
  if (target == "length") return b.length[c];
  if (target == "width") return b.width[c];
  if (target == "height") return b.height[c];
  return b.heading[c];
}

// The effect's parameters, drawn within what the chosen windows hold.
PlantedEffect draw_effect(PlantedFamily family, const PlantedDraw& d, const std::array<int, kClasses>& boxes, TrackingRng& rng) {
  PlantedEffect e;
  e.family = family;
  auto& p = e.params;
  auto choose = [&](std::initializer_list<const char*> options) {
    return std::string(*(options.begin() + pick(rng, static_cast<int>(options.size()))));
  };
  switch (family) {
    case PlantedFamily::Lag:
      e.feature = "radial_velocity", e.target = "position_along";
      p["lag_s"] = uni(rng, 0.05, 0.3);
      break;
    case PlantedFamily::AspectSize:
      e.feature = "heading_to_line_of_sight", e.target = choose({"length", "width"});
      p["share"] = uni(rng, 0.1, 0.3);
      break;
    case PlantedFamily::AnnotationSize:
      e.feature = choose({"occlusion", "truncation"}), e.target = choose({"length", "width"});
      p["share_per_level"] = uni(rng, 0.08, 0.2);
      break;
    case PlantedFamily::Spread:
      e.feature = choose({"speed", "range"}), e.target = choose({"position_along", "position_across"});
      p["gain"] = uni(rng, 1.5, 4);
      break;
    case PlantedFamily::AzimuthDropout: {
      e.feature = "azimuth", e.target = "detection";
      const double width = uni(rng, 15, 40) * kDeg;
      const double lo = uni(rng, d.azimuth_lo, std::max(d.azimuth_lo, d.azimuth_hi - width));
      p["azimuth_lo_deg"] = lo / kDeg, p["azimuth_hi_deg"] = (lo + width) / kDeg;
      p["factor"] = uni(rng, 0, 0.3);
      break;
    }
    case PlantedFamily::RangeDropout:
      e.feature = "range", e.target = "detection";
      p["range_m"] = uni(rng, d.range_lo, d.range_hi);
      p["factor"] = uni(rng, 0, 0.3);
      break;
    case PlantedFamily::ClassBias: {
      std::vector<int> classes;
      for (int c = 0; c < kClasses; ++c)
        if (boxes[c] >= 300) classes.push_back(c);
      const int c = classes.empty() ? 0 : classes[pick(rng, static_cast<int>(classes.size()))];
      e.feature = choose({"speed", "heading_to_line_of_sight", "azimuth"});
      e.target = choose({"position_along", "position_across", "length", "width", "heading"});
      p["class"] = c;
      p["amplitude"] = uni(rng, 4, 8) * base_sigma(d.base, e.target, c) * (uni(rng, 0, 1) < 0.5 ? -1 : 1);
      break;
    }
    case PlantedFamily::FpCell: {
      e.feature = "azimuth", e.features = {"range", "azimuth"}, e.target = kFalsePositivesTarget;
      const double width = uni(rng, 10, 30) * kDeg;
      const double lo = uni(rng, d.azimuth_lo, std::max(d.azimuth_lo, d.azimuth_hi - width));
      const double r0 = uni(rng, 5, 40);
      p["class"] = pick(rng, kClasses);
      p["azimuth_lo_deg"] = lo / kDeg, p["azimuth_hi_deg"] = (lo + width) / kDeg;
      p["range_lo_m"] = r0, p["range_hi_m"] = r0 + uni(rng, 5, 15);
      p["rate_per_frame"] = uni(rng, 0.3, 1.0);
      break;
    }
    case PlantedFamily::Control: break;
  }
  if (e.features.empty() && !e.feature.empty()) e.features = {e.feature};
  return e;
}

// An AB3DMOT line for a box given in the Velodyne frame (centre, size l w h, heading): the exact
// inverse of KittiBoxConverter::convert.
std::string ab3dmot_line(int frame, int cls, double score, const Eigen::Vector3d& centre, const Eigen::Vector3d& size,
                         double heading, const KittiBoxConverter& conv) {
  const Eigen::Matrix3d rinv = conv.rect_to_velo_rotation.inverse();
  const Eigen::Vector3d bottom =
      rinv * (centre - conv.rect_to_velo_translation) + Eigen::Vector3d(0, size.z() / 2, 0);  // camera y down
  const Eigen::Vector3d fwd = rinv * Eigen::Vector3d(std::cos(heading), std::sin(heading), 0);
  const double ry = std::atan2(-fwd.z(), fwd.x());
  const int type_id = cls == 0 ? 2 : cls == 1 ? 1 : 3;
  char line[256];
  std::snprintf(line, sizeof line, "%d,%d,0,0,100,100,%.3f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.5f,-10\n", frame, type_id,
                score, size.z(), size.y(), size.x(), bottom.x(), bottom.y(), bottom.z(), ry);
  return line;
}

// The planted feature's value scaled to [0, 1] for class_bias.
double class_bias_x(const PlantedDraw& d, const PlantedObject& o) {
  const std::string& f = d.effect.feature;
  if (f == "speed") return std::clamp(o.speed / 10, 0.0, 1.0);
  if (f == "heading_to_line_of_sight") return o.aspect;
  return std::clamp((o.azimuth - d.azimuth_lo) / std::max(d.azimuth_hi - d.azimuth_lo, 1e-6), 0.0, 1.0);
}

// The errors of one detection: base draws (the same draws whatever the family, so a draw and its
// control with the same seed differ only by the effect), then the planted effect.
struct Errors {
  double along = 0, across = 0, heading = 0, score = 0, u = 0;
  Eigen::Vector3d size = Eigen::Vector3d::Zero();  // length, width, height
  double planted = 0;  // the effect's part of the planted target's error
};

double target_error(const Errors& e, const std::string& target) {
  if (target == "position_along") return e.along;
  if (target == "position_across") return e.across;
  if (target == "length") return e.size.x();
  if (target == "width") return e.size.y();
  if (target == "height") return e.size.z();
  return e.heading;
}

PlantedObject object_of(const Truth& t) {
  PlantedObject o;
  o.cls = t.cls, o.range = t.range, o.azimuth = t.azimuth;
  o.radial_velocity = t.v.dot(t.u), o.speed = t.v.norm(), o.aspect = t.aspect;
  o.occlusion = t.o->occluded, o.truncation = std::clamp(t.o->truncated, 0.0, 1.0);
  o.length = t.o->object.size.x(), o.width = t.o->object.size.y();
  return o;
}

// The errors of one detection: base draws (the same draws whatever the family, so a draw and its
// control with the same seed differ only by the effect), then the planted effect's mean (the
// public planted_mean_error, so the scorer's truth is the generator's).
Errors draw_errors(const PlantedDraw& d, const Truth& t, TrackingRng& rng) {
  const PlantedBaseModel& b = d.base;
  const int c = t.cls;
  const PlantedObject o = object_of(t);
  Errors e;
  e.u = uni(rng, 0, 1), e.score = uni(rng, 1, 8);
  double sa = b.along[c], sc = b.across[c];
  const PlantedFamily fam = d.effect.family;
  if (fam == PlantedFamily::Spread) (d.effect.target == "position_along" ? sa : sc) = planted_sigma(d, d.effect.target, o);
  e.along = sa * gauss(rng), e.across = sc * gauss(rng);
  e.size = {b.length[c] * gauss(rng), b.width[c] * gauss(rng), b.height[c] * gauss(rng)};
  e.heading = b.heading[c] * gauss(rng);
  const Errors base = e;
  if (!d.effect.target.empty() && d.effect.target != "detection" && d.effect.target != kFalsePositivesTarget) {
    const double m = planted_mean_error(d, d.effect.target, o);
    const std::string& tg = d.effect.target;
    if (tg == "position_along") e.along += m;
    else if (tg == "position_across") e.across += m;
    else if (tg == "heading") e.heading += m;
    else e.size[tg == "length" ? 0 : tg == "width" ? 1 : 2] += m;
  }
  // The lag's part across the line of sight (not the planted target, and not a loop feature).
  if (fam == PlantedFamily::Lag) e.across += -d.effect.params.at("lag_s") * t.v.dot(t.left);
  e.planted = target_error(e, d.effect.target) - target_error(base, d.effect.target);
  return e;
}

double detection_probability(const PlantedDraw& d, const Truth& t) {
  return planted_detection_probability(d, object_of(t));
}

// A false positive of class c at (range, azimuth) on the ground, its class's typical box.
std::string false_positive(int frame, int c, double range, double az, TrackingRng& rng, const KittiBoxConverter& conv) {
  const Eigen::Vector3d box = kClassBox[c];
  const Eigen::Vector3d centre(range * std::cos(az), range * std::sin(az), -1.73 + box.z() / 2);
  return ab3dmot_line(frame, c, uni(rng, 0.5, 4), centre, box, uni(rng, -kPi, kPi), conv);
}

// The window's labels as they are in the source, frames renumbered from 0, and a DontCare line in its
// last frame (the reader takes the last labelled frame as the sequence's end).
std::string window_labels(const fs::path& source, const PlantedSequence& w) {
  const fs::path path = source / "label_02" / (w.name + ".txt");
  std::ifstream in(path);
  if (!in) throw Error("planted tracking: " + path.string() + ": cannot open");
  std::string out, line;
  while (std::getline(in, line)) {
    std::istringstream ss(line);
    int frame = -1;
    if (!(ss >> frame)) continue;
    if (frame < w.first_frame || frame >= w.first_frame + w.frames) continue;
    std::string rest;
    std::getline(ss, rest);
    out += std::to_string(frame - w.first_frame) + rest + "\n";
  }
  out += std::to_string(w.frames - 1) + " -1 DontCare -1 -1 -10 0 0 100 100 -1 -1 -1 -1000 -1000 -1000 -10\n";
  return out;
}

// What an ideal refit of the planted effect could reach: per class (detection: per class and
// occlusion level) the planted target's error centred on its mean, with and without the effect's part.
struct IdealSums {
  std::map<int, std::vector<std::array<double, 2>>> groups;  // group: (with effect, without) per object
  void add(int group, double with, double without) { groups[group].push_back({with, without}); }
  PlantedStats stats(bool detection) const {
    double before = 0, after = 0, n = 0;
    for (const auto& [g, v] : groups) {
      double mean_with = 0, mean_without = 0;
      for (const auto& x : v) mean_with += x[0] / v.size(), mean_without += x[1] / v.size();
      for (const auto& x : v) {
        before += (x[0] - mean_with) * (x[0] - mean_with);
        // Detection: x = (detected, probability with the effect); errors: the base error centred.
        after += detection ? (x[0] - x[1]) * (x[0] - x[1]) : (x[1] - mean_without) * (x[1] - mean_without);
        n += 1;
      }
    }
    PlantedStats out;
    if (n > 0) out.ideal_before = std::sqrt(before / n), out.ideal_after = std::sqrt(after / n);
    return out;
  }
};

void write_window(const fs::path& dir, const PlantedDraw& d, Window& w, TrackingRng& rng, TrackingRng& cell_rng, IdealSums& ideal) {
  fill_truth(w);
  const KittiBoxConverter conv(w.seq.calib);
  std::array<std::string, kClasses> dets;
  size_t next = 0;
  const auto& p = d.effect.params;
  for (int f = 0; f < w.where.frames; ++f) {
    for (; next < w.truth.size() && w.truth[next].frame == f; ++next) {
      const Truth& t = w.truth[next];
      const Errors e = draw_errors(d, t, rng);
      const double pd = detection_probability(d, t);
      if (d.effect.target == "detection") ideal.add(t.cls * 4 + std::min(t.o->occluded, 3), e.u <= pd, pd);
      if (e.u > pd) continue;
      if (d.effect.family != PlantedFamily::Spread && !d.effect.target.empty() && d.effect.target != "detection" &&
          d.effect.target != kFalsePositivesTarget)
        ideal.add(t.cls, target_error(e, d.effect.target), target_error(e, d.effect.target) - e.planted);
      const Eigen::Vector2d bev = t.bev + e.along * t.u + e.across * t.left;
      const Eigen::Vector3d centre(bev.x(), bev.y(), t.o->object.position.z());
      const Eigen::Vector3d size = (t.o->object.size + e.size).cwiseMax(0.1);
      dets[t.cls] += ab3dmot_line(f, t.cls, e.score, centre, size, t.o->object.heading + e.heading, conv);
    }
    for (int c = 0; c < kClasses; ++c) {
      const int n = std::poisson_distribution<int>(d.base.fp_rate[c])(rng);
      for (int k = 0; k < n; ++k)
        dets[c] += false_positive(f, c, uni(rng, 5, 50), uni(rng, d.azimuth_lo, d.azimuth_hi), rng, conv);
    }
    if (d.effect.family == PlantedFamily::FpCell) {
      const int c = static_cast<int>(p.at("class"));
      const int n = std::poisson_distribution<int>(p.at("rate_per_frame"))(cell_rng);
      for (int k = 0; k < n; ++k) {
        const double r = uni(cell_rng, p.at("range_lo_m"), p.at("range_hi_m"));
        const double az = uni(cell_rng, p.at("azimuth_lo_deg"), p.at("azimuth_hi_deg")) * kDeg;
        dets[c] += false_positive(f, c, r, az, cell_rng, conv);
      }
    }
  }
  const std::string& name = w.where.name;
  write_file_atomically(dir / "label_02" / (name + ".txt"), window_labels(d.source, w.where));
  fs::copy_file(d.source / "calib" / (name + ".txt"), dir / "calib" / (name + ".txt"),
                fs::copy_options::overwrite_existing);
  for (int c = 0; c < kClasses; ++c)
    write_file_atomically(dir / "detection" / (std::string("pointrcnn_") + kClassNames[c] + "_val") / (name + ".txt"),
                          dets[c]);
}

}  // namespace

std::string to_string(PlantedFamily f) { return kPlantedFamilyNames[static_cast<int>(f)]; }

PlantedFamily planted_family_from_string(const std::string& name) {
  std::string valid;
  for (int k = 0; k < kPlantedFamilies; ++k) {
    if (name == kPlantedFamilyNames[k]) return static_cast<PlantedFamily>(k);
    valid += std::string(k ? ", " : "") + kPlantedFamilyNames[k];
  }
  throw Error("planted tracking: unknown family \"" + name + "\" (valid: " + valid + ")");
}

double planted_mean_error(const PlantedDraw& d, const std::string& target, const PlantedObject& o) {
  const PlantedEffect& e = d.effect;
  if (target != e.target) return 0;
  const auto& p = e.params;
  const double size = target == "length" ? o.length : o.width;
  switch (e.family) {
    case PlantedFamily::Lag: return target == "position_along" ? -p.at("lag_s") * o.radial_velocity : 0;
    case PlantedFamily::AspectSize: return -p.at("share") * size * (target == "length" ? 1 - o.aspect : o.aspect);
    case PlantedFamily::AnnotationSize: {
      const double level = e.feature == "occlusion" ? o.occlusion : std::clamp(o.truncation, 0.0, 1.0);
      return -std::min(0.6, p.at("share_per_level") * level) * size;
    }
    case PlantedFamily::ClassBias:
      return o.cls == static_cast<int>(p.at("class")) ? p.at("amplitude") * (class_bias_x(d, o) - 0.5) : 0;
    default: return 0;
  }
}

double planted_detection_probability(const PlantedDraw& d, const PlantedObject& o) {
  double pd = d.base.detection[o.cls] * (1 - d.base.occlusion_loss * std::min(o.occlusion, 2.0));
  const auto& p = d.effect.params;
  if (d.effect.family == PlantedFamily::AzimuthDropout && o.azimuth >= p.at("azimuth_lo_deg") * kDeg &&
      o.azimuth <= p.at("azimuth_hi_deg") * kDeg)
    pd *= p.at("factor");
  if (d.effect.family == PlantedFamily::RangeDropout && o.range >= p.at("range_m")) pd *= p.at("factor");
  return pd;
}

double planted_sigma(const PlantedDraw& d, const std::string& target, const PlantedObject& o) {
  static const std::vector<std::string> known = {"position_along", "position_across", "length", "width", "height",
                                                 "heading"};
  if (std::find(known.begin(), known.end(), target) == known.end())
    return std::numeric_limits<double>::quiet_NaN();
  const double s = base_sigma(d.base, target, o.cls);
  if (d.effect.family != PlantedFamily::Spread || target != d.effect.target) return s;
  const double x = d.effect.feature == "speed" ? o.speed / 10 : o.range / 40;
  return s * (1 + d.effect.params.at("gain") * x);
}

PlantedDraw plan_planted_tracking(PlantedFamily family, const PlantedTrackingOptions& o) {
  if (o.sequences < 1) throw Error("planted tracking: sequences must be >= 1, got " + std::to_string(o.sequences));
  if (o.max_frames < 0) throw Error("planted tracking: max_frames must be >= 0, got " + std::to_string(o.max_frames));
  TrackingRng rng(o.seed);
  PlantedDraw d;
  d.source = o.source, d.seed = o.seed;
  const std::vector<Window> windows = choose_windows(o, rng);
  std::vector<double> az, range;
  std::array<int, kClasses> boxes{};
  for (const Window& w : windows) {
    d.sequences.push_back(w.where);
    for (const Truth& t : w.truth) az.push_back(t.azimuth), range.push_back(t.range), ++boxes[t.cls];
  }
  d.azimuth_lo = quantile(az, 0.05), d.azimuth_hi = quantile(az, 0.95);
  d.range_lo = quantile(range, 0.4), d.range_hi = quantile(range, 0.8);
  d.base = draw_base(rng);
  d.effect = draw_effect(family, d, boxes, rng);
  return d;
}

PlantedStats write_planted_tracking(const fs::path& dir, const PlantedDraw& d) {
  for (const char* sub : {"label_02", "calib", "detection/pointrcnn_Car_val", "detection/pointrcnn_Pedestrian_val",
                          "detection/pointrcnn_Cyclist_val"})
    fs::create_directories(dir / sub);
  // Streams of their own: the base noise (the same for every family at one seed) and the fp cell's.
  TrackingRng rng(d.seed ^ 0x9a7e5eed0b1ec75ULL), cell_rng(d.seed ^ 0xfce11c0ffee5ULL);
  std::string seqmap;
  IdealSums ideal;
  for (const PlantedSequence& where : d.sequences) {
    Window w;
    w.where = where;
    w.seq = read_kitti_tracking_sequence(d.source, where.name, "planted_none");
    if (where.first_frame + where.frames > static_cast<int>(w.seq.frames.size()))
      throw Error("planted tracking: " + (d.source / "label_02" / (where.name + ".txt")).string() +
                  ": has fewer frames than the window asks");
    write_window(dir, d, w, rng, cell_rng, ideal);
    char line[64];
    std::snprintf(line, sizeof line, "%s empty 000000 %06d\n", where.name.c_str(), where.frames);
    seqmap += line;
  }
  write_file_atomically(dir / "evaluate_tracking.seqmap.val", seqmap);
  return ideal.stats(d.effect.target == "detection");
}

}  // namespace lidarsim::data
