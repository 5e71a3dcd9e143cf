#include "sensor/tracking.h"

#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <string>

#include "common/error.h"

namespace lidarsim::sensor {

namespace {
void require_positive(double v, const char* field) {
  if (!std::isfinite(v) || v <= 0)
    throw input_error("tracker config", field, "must be a positive finite number, got " + std::to_string(v));
}
}  // namespace

void TrackerConfig::validate() const {
  require_positive(process_accel_std, "process_accel_std");
  require_positive(measurement_std, "measurement_std");
  require_positive(initial_velocity_std, "initial_velocity_std");
  require_positive(gate_chi2, "gate_chi2");
  if (confirm_hits < 1) throw input_error("tracker config", "confirm_hits", "must be >= 1");
  if (max_coast_frames < 0) throw input_error("tracker config", "max_coast_frames", "must be >= 0");
}

const char* to_string(TrackState s) {
  switch (s) {
    case TrackState::Tentative: return "tentative";
    case TrackState::Confirmed: return "confirmed";
    case TrackState::Coasting: return "coasting";
    case TrackState::Deleted: return "deleted";
  }
  return "?";
}

Tracker::Tracker(TrackerConfig config) : config_(config) { config_.validate(); }

void Tracker::reset() {
  tracks_.clear();
  started_ = false;
  next_id_ = 1;
}

void Tracker::transition(double dt, Eigen::Matrix4d& F, Eigen::Matrix4d& Q) const {
  F = Eigen::Matrix4d::Identity();
  F(0, 2) = F(1, 3) = dt;
  const double q = config_.process_accel_std * config_.process_accel_std;
  const double a = q * dt * dt * dt * dt / 4, b = q * dt * dt * dt / 2, c = q * dt * dt;
  Q = Eigen::Matrix4d::Zero();
  Q(0, 0) = Q(1, 1) = a;
  Q(0, 2) = Q(2, 0) = Q(1, 3) = Q(3, 1) = b;
  Q(2, 2) = Q(3, 3) = c;
}

void Tracker::predict(Track& t, const Eigen::Matrix4d& F, const Eigen::Matrix4d& Q, double dt) const {
  t.x = F * t.x;
  t.P = F * t.P * F.transpose() + Q;
  // Constant velocity also in z (the filter tracks x, y only), so coasting boxes move on.
  t.object.position.z() += t.object.velocity.z() * dt;
}

void Tracker::correct(Track& t, const Object& det) const {
  const double r = config_.measurement_std * config_.measurement_std;
  const Eigen::Vector2d y = det.position.head<2>() - t.x.head<2>();
  const Eigen::Matrix2d S = t.P.topLeftCorner<2, 2>() + r * Eigen::Matrix2d::Identity();
  const Eigen::Matrix<double, 4, 2> K = t.P.leftCols<2>() * S.inverse();
  t.x += K * y;
  Eigen::Matrix<double, 2, 4> H = Eigen::Matrix<double, 2, 4>::Zero();
  H(0, 0) = H(1, 1) = 1;
  t.P = (Eigen::Matrix4d::Identity() - K * H) * t.P;
  t.P = 0.5 * (t.P + t.P.transpose());
}

Track Tracker::make_track(const Object& det, int index) {
  Track t;
  t.id = next_id_++;
  t.state = config_.confirm_hits <= 1 ? TrackState::Confirmed : TrackState::Tentative;
  t.object = det;
  t.x << det.position.x(), det.position.y(), det.velocity.x(), det.velocity.y();
  t.P.setZero();
  const double r = config_.measurement_std * config_.measurement_std;
  const double pv = config_.initial_velocity_std * config_.initial_velocity_std;
  t.P.diagonal() << r, r, pv, pv;
  t.hits = 1;
  t.source_id = det.id;
  t.detection_index = index;
  t.object.id = t.id;
  return t;
}

namespace {
int find_root(std::vector<int>& parent, int i) {
  while (parent[i] != i) i = parent[i] = parent[parent[i]];
  return i;
}
}  // namespace

void Tracker::associate(const std::vector<Object>& detections) {
  gate_pairs(detections);
  if (edges_.empty()) return;
  const int n_groups = group_pairs();
  for (int gi = 0; gi < n_groups; ++gi) solve_group(groups_[gi]);
}

// Gated pairs; tracks are nodes 0..nt-1, detections nt..nt+nd-1 of a union-find forest. The
// detections sorted by x let each track visit only those within its gate's reach in x.
void Tracker::gate_pairs(const std::vector<Object>& detections) {
  const int nt = static_cast<int>(tracks_.size()), nd = static_cast<int>(detections.size());
  const double r = config_.measurement_std * config_.measurement_std;
  by_x_.resize(nd);
  for (int j = 0; j < nd; ++j) by_x_[j] = j;
  std::sort(by_x_.begin(), by_x_.end(),
            [&](int a, int b) { return detections[a].position.x() < detections[b].position.x(); });
  xs_.resize(nd);
  for (int k = 0; k < nd; ++k) xs_[k] = detections[by_x_[k]].position.x();

  edges_.clear();
  parent_.resize(nt + nd);
  for (int i = 0; i < nt + nd; ++i) parent_[i] = i;
  for (int i = 0; i < nt; ++i) {
    const Track& t = tracks_[i];
    const Eigen::Matrix2d S = t.P.topLeftCorner<2, 2>() + r * Eigen::Matrix2d::Identity();
    const Eigen::Matrix2d S_inv = S.inverse();
    const double reach = std::sqrt(config_.gate_chi2 * S(0, 0)) * (1 + 1e-9) + 1e-9;
    const auto first = std::lower_bound(xs_.begin(), xs_.end(), t.x(0) - reach);
    for (auto it = first; it != xs_.end() && *it <= t.x(0) + reach; ++it) {
      const int j = by_x_[it - xs_.begin()];
      const Object& d = detections[j];
      if (config_.same_class_only && d.cls != t.object.cls) continue;
      const Eigen::Vector2d y = d.position.head<2>() - t.x.head<2>();
      const double m2 = y.dot(S_inv * y);
      if (!(m2 <= config_.gate_chi2)) continue;
      edges_.push_back({i, j, m2});
      const int a = find_root(parent_, i), b = find_root(parent_, nt + j);
      if (a != b) parent_[a] = b;
    }
  }
}

// Connected groups of gated pairs, in the order of their first edge; returns their count.
// groups_ keeps its inner vectors' capacity from frame to frame.
int Tracker::group_pairs() {
  const int nodes = static_cast<int>(parent_.size());
  group_of_root_.assign(nodes, -1);
  int n_groups = 0;
  for (int e = 0; e < static_cast<int>(edges_.size()); ++e) {
    const int root = find_root(parent_, edges_[e].track);
    if (group_of_root_[root] < 0) {
      group_of_root_[root] = n_groups;
      if (n_groups == static_cast<int>(groups_.size())) groups_.emplace_back();
      groups_[n_groups++].clear();
    }
    groups_[group_of_root_[root]].push_back(e);
  }
  local_of_.assign(nodes, -1);
  return n_groups;
}

// The least-cost assignment within one group; a lone pair needs no solver.
void Tracker::solve_group(const std::vector<int>& group) {
  const int nt = static_cast<int>(tracks_.size());
  if (group.size() == 1) {
    const Edge& e = edges_[group[0]];
    tracks_[e.track].detection_index = e.detection;
    det_assigned_[e.detection] = e.track;
    return;
  }
  group_tracks_.clear();
  group_dets_.clear();
  for (int e : group) {
    const Edge& g = edges_[e];
    if (local_of_[g.track] < 0) {
      local_of_[g.track] = static_cast<int>(group_tracks_.size());
      group_tracks_.push_back(g.track);
    }
    if (local_of_[nt + g.detection] < 0) {
      local_of_[nt + g.detection] = static_cast<int>(group_dets_.size());
      group_dets_.push_back(g.detection);
    }
  }
  const double outside = config_.gate_chi2 * 10 + 1e3;  // finite, so the solver stays simple
  cost_.setConstant(static_cast<int>(group_tracks_.size()), static_cast<int>(group_dets_.size()), outside);
  for (int e : group) {
    const Edge& g = edges_[e];
    cost_(local_of_[g.track], local_of_[nt + g.detection]) = g.m2;
  }
  const std::vector<int>& assign = solver_.solve(cost_);
  for (int li = 0; li < static_cast<int>(group_tracks_.size()); ++li) {
    const int lj = assign[li];
    if (lj < 0 || cost_(li, lj) > config_.gate_chi2) continue;
    const int i = group_tracks_[li], j = group_dets_[lj];
    tracks_[i].detection_index = j;
    det_assigned_[j] = i;
  }
}

const std::vector<Track>& Tracker::update(const std::vector<Object>& detections, double time) {
  const double dt = started_ ? time - last_time_ : 0.0;
  if (!std::isfinite(time) || (started_ && dt <= 0))
    throw Error("tracker: time: must increase from frame to frame, got " + std::to_string(time) +
                " after " + std::to_string(last_time_));
  for (const Object& d : detections)
    if (!d.position.allFinite()) throw Error("tracker: detection position: must be finite");
  started_ = true;
  last_time_ = time;

  Eigen::Matrix4d F, Q;  // the same for every track: built once per frame
  transition(dt, F, Q);
  for (Track& t : tracks_) {
    predict(t, F, Q, dt);
    t.detection_index = -1;
  }

  // Association: Mahalanobis distance of each detection to each predicted track, inside the gate.
  // Only gated pairs can be associated, and the minimum-cost assignment over the full matrix
  // (gated pairs at their distance, every other pair at one large constant) is the union of the
  // minimum-cost assignments of the connected groups of gated pairs: the constant makes it
  // maximise the gated pairs used per group, then minimise their distance, independently per
  // group. So the candidates come from detections sorted by x (a track's gate ellipse spans
  // +-sqrt(gate S_xx) in x), and the Hungarian solver sees each group alone: nearly always one
  // track and one detection, where it has nothing to do.
  const int nt = static_cast<int>(tracks_.size()), nd = static_cast<int>(detections.size());
  det_assigned_.assign(nd, -1);
  if (nt > 0 && nd > 0) associate(detections);

  // Update and manage states; deleted tracks are dropped, ids never come back.
  scratch_.clear();
  for (Track& t : tracks_) {
    ++t.age;
    if (t.detection_index >= 0) {
      const Object& d = detections[t.detection_index];
      correct(t, d);
      const int id = t.id;
      t.object = d;  // class, size, heading, z, visibility, score from the measurement
      t.object.id = id;
      t.source_id = d.id;
      ++t.hits;
      t.misses = 0;
      if (t.state == TrackState::Tentative && t.hits >= config_.confirm_hits) t.state = TrackState::Confirmed;
      if (t.state == TrackState::Coasting) t.state = TrackState::Confirmed;
    } else {
      ++t.misses;
      t.hits = 0;
      if (t.state == TrackState::Tentative) t.state = TrackState::Deleted;
      else if (t.misses > config_.max_coast_frames) t.state = TrackState::Deleted;
      else t.state = TrackState::Coasting;
      t.object.visible_fraction = 0;
    }
    t.object.position.x() = t.x(0);
    t.object.position.y() = t.x(1);
    t.object.velocity.x() = t.x(2);
    t.object.velocity.y() = t.x(3);
    if (t.state != TrackState::Deleted) scratch_.push_back(std::move(t));  // tracks_ is rebuilt below
  }
  for (int j = 0; j < nd; ++j)
    if (det_assigned_[j] < 0) scratch_.push_back(make_track(detections[j], j));
  tracks_.swap(scratch_);
  return tracks_;
}

void Tracker::reported(std::vector<Object>& out) const {
  out.clear();
  for (const Track& t : tracks_)
    if (t.state == TrackState::Confirmed || t.state == TrackState::Coasting) out.push_back(t.object);
}

}  // namespace lidarsim::sensor
