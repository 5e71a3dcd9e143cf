// Reading a KITTI tracking folder and turning it into ObjectRecords (matched errors, features).
#include <algorithm>
#include <cmath>
#include <map>
#include <numbers>

#include "common/error.h"
#include "qualify/objects/object_folds.h"
#include "qualify/objects/objects.h"

namespace fs = std::filesystem;

namespace lidarsim::qualify {

using obj::class_index;
using obj::kNaN;
using obj::wrap;

TrackingData load_tracking(const fs::path& dir, const std::string& seqmap, const std::string& detector,
                           int min_sequences) {
  if (!fs::is_directory(dir)) throw input_error(dir.string(), "--kitti-tracking", "not a directory");
  for (const char* sub : {"label_02", "calib"})
    if (!fs::is_directory(dir / sub))
      throw input_error((dir / sub).string(), "layout", "missing folder (expected label_02/, calib/, detection/)");
  bool any_detection_folder = false;
  for (const std::string& c : kObjectClasses)
    any_detection_folder |= fs::is_directory(dir / "detection" / (detector + "_" + c + "_val"));
  if (!any_detection_folder)
    throw input_error((dir / "detection").string(), "layout",
                      "no " + detector + "_{Car,Pedestrian,Cyclist}_val/ folder (AB3DMOT layout)");

  std::vector<std::string> names;
  const fs::path map_path = seqmap.empty() ? dir / "evaluate_tracking.seqmap.val" : fs::path(seqmap);
  if (!seqmap.empty() || fs::exists(map_path)) {
    if (!fs::exists(map_path)) throw input_error(map_path.string(), "--seqmap", "file not found");
    for (const std::string& n : data::read_kitti_seqmap(map_path))
      if (fs::exists(dir / "label_02" / (n + ".txt"))) names.push_back(n);
  } else {
    for (const auto& e : fs::directory_iterator(dir / "label_02"))
      if (e.path().extension() == ".txt") names.push_back(e.path().stem().string());
    std::sort(names.begin(), names.end());
  }
  if (static_cast<int>(names.size()) < min_sequences)
    throw input_error((dir / "label_02").string(), "sequences",
                      "found " + std::to_string(names.size()) + " sequence(s) with labels, need at least " +
                          std::to_string(min_sequences));
  TrackingData d;
  for (const std::string& n : names) {
    const fs::path calib = dir / "calib" / (n + ".txt");
    if (!fs::exists(calib)) throw input_error(calib.string(), "file", "missing (calib of sequence " + n + ")");
    bool has_detections = false;
    for (const std::string& c : kObjectClasses)
      has_detections |= fs::exists(dir / "detection" / (detector + "_" + c + "_val") / (n + ".txt"));
    if (!has_detections)
      throw input_error((dir / "detection").string(), "file",
                        "no " + detector + "_*_val/" + n + ".txt for sequence " + n + " (labels without detections)");
    d.names.push_back(n);
    d.kitti.push_back(data::read_kitti_tracking_sequence(dir, n, detector));
    d.calib.push_back(data::to_calibration_sequence(d.kitti.back()));
  }
  return d;
}

namespace {

int bin_index(const std::vector<double>& edges, double v) {
  return std::max(0, static_cast<int>(std::upper_bound(edges.begin(), edges.end(), v) - edges.begin()) - 1);
}

// A matched detection's errors: position along and across the line of sight `u`, size, heading.
void fill_errors(const sensor::Object& g, const sensor::Object& d, const Eigen::Vector2d& u, ObjectRecord& r) {
  const Eigen::Vector2d left(-u.y(), u.x());
  const Eigen::Vector2d e = (d.position - g.position).head<2>();
  r.value[0] = e.dot(u);
  r.value[1] = e.dot(left);
  r.value[2] = d.size.x() - g.size.x();
  r.value[3] = d.size.y() - g.size.y();
  r.value[4] = d.size.z() - g.size.z();
  double h = wrap(d.heading - g.heading);
  if (std::abs(h) > std::numbers::pi / 2) h = wrap(h - std::numbers::pi);  // 180-degree flips are modelled apart
  r.value[5] = h;
}

// The ground-truth track's velocity and acceleration at frame f: central differences where the
// track has both neighbours, else a one-sided velocity.
void track_motion(const std::map<int, Eigen::Vector3d>& tp, int f, const Eigen::Vector3d& position, double dt,
                  Eigen::Vector3d& v, Eigen::Vector3d& a) {
  const auto prev = tp.find(f - 1), next = tp.find(f + 1);
  v = a = Eigen::Vector3d::Zero();
  if (prev != tp.end() && next != tp.end()) {
    v = (next->second - prev->second) / (2 * dt);
    a = (next->second - 2 * position + prev->second) / (dt * dt);
  } else if (next != tp.end()) {
    v = (next->second - position) / dt;
  } else if (prev != tp.end()) {
    v = (position - prev->second) / dt;
  }
}

// One ground-truth object of frame f: its bins, its errors if `det` matched it, and the features
// the loop ranks, from the object and its track `tp`.
ObjectRecord object_record(int s, int f, const sensor::Object& g, const data::KittiTrackingObject& k,
                           const sensor::Object* det, const std::map<int, Eigen::Vector3d>& tp, double dt,
                           const sensor::FitOptions& opt) {
  ObjectRecord r;
  r.seq = s;
  r.frame = f;
  r.track = g.id;
  r.cls = class_index(g.cls);
  const Eigen::Vector2d bev = g.position.head<2>();
  const double range = bev.norm();
  const Eigen::Vector2d u = range > 1e-6 ? Eigen::Vector2d(bev / range) : Eigen::Vector2d(1, 0);
  r.range_bin = bin_index(opt.range_bin_edges, range);
  r.visibility_bin = bin_index(opt.visibility_bin_edges, g.visible_fraction);
  r.value.fill(kNaN);
  if (det) {
    r.detected = true;
    fill_errors(g, *det, u, r);
  }
  r.value[kDetectionTarget] = r.detected ? 1.0 : 0.0;
  Eigen::Vector3d v, a;
  track_motion(tp, f, g.position, dt, v, a);
  const Eigen::Vector2d fwd(std::cos(g.heading), std::sin(g.heading));
  const Eigen::Vector2d side(-fwd.y(), fwd.x());
  const double az = std::atan2(bev.y(), bev.x());
  double rel = std::abs(wrap(g.heading - az));
  if (rel > std::numbers::pi / 2) rel = std::numbers::pi - rel;
  r.feature = {range,
               az,
               v.head<2>().dot(u),
               v.head<2>().norm(),
               v.head<2>().dot(fwd),
               v.head<2>().dot(side),
               a.head<2>().norm(),
               rel,
               double(std::clamp(k.occluded, 0, 3)),
               g.truncation,  // the label's truncated clamped to [0, 1], what the KPI manager reads
               double(r.cls),
               g.size.x(),
               g.size.y(),
               g.size.z(),
               double(f - tp.begin()->first)};
  return r;
}

// The frame's false positives per class: unmatched detections above the score threshold that are
// not near an object of another class (fr.others); each also as a record for the rate candidates.
PerClass<int> frame_false_positives(const sensor::CalibrationFrame& fr, const std::vector<char>& used,
                                    const sensor::FitOptions& opt, ObjectSet& out) {
  PerClass<int> fp{};
  for (size_t j = 0; j < fr.detections.size(); ++j) {
    const sensor::Object& d = fr.detections[j];
    if (used[j] || d.score <= opt.min_score) continue;
    const int ci = class_index(d.cls);
    if (ci < 0) continue;
    bool near_other = false;
    for (const sensor::Object& o : fr.others)
      if ((o.position - d.position).head<2>().norm() <= opt.gate) near_other = true;
    if (near_other) continue;
    ++fp[ci];
    out.fp_records.push_back({static_cast<int>(out.frame_seq.size()), ci, d.position.head<2>().norm(),
                              std::atan2(d.position.y(), d.position.x()), d.score});
  }
  return fp;
}

}  // namespace

ObjectSet collect_objects(const TrackingData& data, const std::vector<int>& sequences,
                          const std::vector<sensor::CalibrationSequence>* detections, const sensor::FitOptions& opt) {
  ObjectSet out;
  for (int s : sequences) {
    const data::KittiTrackingSequence& ks = data.kitti.at(s);
    const sensor::CalibrationSequence& cs = detections ? detections->at(s) : data.calib.at(s);
    // Truth of the three classes per frame, in the order to_calibration_sequence keeps them.
    std::vector<std::vector<const data::KittiTrackingObject*>> truth(ks.frames.size());
    std::map<int, std::map<int, Eigen::Vector3d>> track_pos;
    for (size_t f = 0; f < ks.frames.size(); ++f)
      for (const auto& o : ks.frames[f].truth)
        if (o.type == "Car" || o.type == "Pedestrian" || o.type == "Cyclist") {
          truth[f].push_back(&o);
          track_pos[o.object.id][static_cast<int>(f)] = o.object.position;
        }
    for (size_t f = 0; f < cs.frames.size() && f < truth.size(); ++f) {
      const sensor::CalibrationFrame& fr = cs.frames[f];
      const std::vector<int> match =
          sensor::match_truth_to_detections(fr.truth, fr.detections, opt.gate, opt.min_score);
      std::vector<char> used(fr.detections.size(), 0);
      for (size_t i = 0; i < fr.truth.size() && i < truth[f].size(); ++i) {
        const sensor::Object& g = fr.truth[i];
        if (match[i] >= 0) used[match[i]] = 1;
        const sensor::Object* det = match[i] >= 0 ? &fr.detections[match[i]] : nullptr;
        out.records.push_back(
            object_record(s, static_cast<int>(f), g, *truth[f][i], det, track_pos[g.id], cs.frame_dt, opt));
      }
      out.false_positives.push_back(frame_false_positives(fr, used, opt, out));
      out.frame_seq.push_back(s);
      out.frame_index.push_back(static_cast<int>(f));
      out.frame_truths.push_back(static_cast<int>(std::min(fr.truth.size(), truth[f].size())));
    }
  }
  return out;
}

}  // namespace lidarsim::qualify
