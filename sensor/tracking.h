#pragma once
// Tracking stage: one Kalman filter per track with a constant-velocity model in x, y (sensor
// or map frame, whichever the caller feeds consistently), gated association of detections to
// tracks by the Mahalanobis distance solved with the Hungarian algorithm, track management
// (tentative -> confirmed -> coasting -> deleted) and stable track ids.
//
// Noise model (state it, so users know what the filter assumes):
//   process:     white acceleration noise per axis, sigma_a = process_accel_std [m/s^2];
//                Q = sigma_a^2 [[dt^4/4, dt^3/2], [dt^3/2, dt^2]] for (position, velocity).
//   measurement: position x, y with independent noise sigma = measurement_std [m].
#include <Eigen/Core>

#include <vector>

#include "sensor/hungarian.h"
#include "sensor/scene.h"

namespace lidarsim::sensor {

struct TrackerConfig {
  double process_accel_std = 2.0;   // m/s^2
  double measurement_std = 0.2;     // m
  double initial_velocity_std = 5;  // m/s, prior on velocity of a new track
  double gate_chi2 = 13.82;         // Mahalanobis^2 gate: chi2, 2 dof, 99.9 %
  int confirm_hits = 2;             // consecutive hits for tentative -> confirmed
  int max_coast_frames = 10;        // frames a confirmed track survives without detection
  bool same_class_only = true;      // associate only detections of the track's class
  void validate() const;            // throws lidarsim::Error naming the field
};

enum class TrackState { Tentative, Confirmed, Coasting, Deleted };
const char* to_string(TrackState s);

struct Track {
  int id = -1;
  TrackState state = TrackState::Tentative;
  Object object;          // the estimate: KF position/velocity, other fields from last detection
  Eigen::Vector4d x;      // state (px, py, vx, vy)
  Eigen::Matrix4d P;      // covariance of x
  int hits = 0;           // consecutive frames with a detection
  int misses = 0;         // consecutive frames without a detection
  int age = 0;            // frames since creation
  int source_id = -1;     // id of the input object last associated (e.g. ground-truth id)
  int detection_index = -1;  // index into this frame's input, -1 when not associated
};

class Tracker {
 public:
  explicit Tracker(TrackerConfig config = {});

  // One frame: predict every track to `time`, associate `detections` (positions in x, y),
  // update, manage states. Returns the live tracks (deleted ones are removed; their ids are
  // never reused). The first call only initialises tracks.
  const std::vector<Track>& update(const std::vector<Object>& detections, double time);

  const std::vector<Track>& tracks() const { return tracks_; }
  // Confirmed and coasting tracks as objects whose id is the track id (coasting ones carry
  // visible_fraction 0: they are predictions, not measurements). Appends to `out` after clear.
  void reported(std::vector<Object>& out) const;
  const TrackerConfig& config() const { return config_; }
  void reset();

 private:
  void transition(double dt, Eigen::Matrix4d& F, Eigen::Matrix4d& Q) const;  // constant velocity over dt, its process noise
  void predict(Track& t, const Eigen::Matrix4d& F, const Eigen::Matrix4d& Q, double dt) const;
  void correct(Track& t, const Object& det) const;
  Track make_track(const Object& det, int index);
  void associate(const std::vector<Object>& detections);  // sets detection_index / det_assigned_
  // The steps of associate.
  void gate_pairs(const std::vector<Object>& detections);
  int group_pairs();
  void solve_group(const std::vector<int>& group);

  TrackerConfig config_;
  std::vector<Track> tracks_;
  std::vector<Track> scratch_;
  Eigen::MatrixXd cost_;
  std::vector<int> det_assigned_;
  // Association scratch (reused, so a frame allocates nothing once warm).
  struct Edge {
    int track, detection;
    double m2;
  };
  std::vector<Edge> edges_;
  std::vector<int> by_x_, parent_, group_of_root_, local_of_, group_tracks_, group_dets_;
  std::vector<double> xs_;
  std::vector<std::vector<int>> groups_;
  HungarianSolver solver_;
  double last_time_ = 0;
  bool started_ = false;
  int next_id_ = 1;
};

}  // namespace lidarsim::sensor
