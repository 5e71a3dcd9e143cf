#pragma once
// KPI manager: turns ground-truth (or tracked) objects into what a real detector reports.
// Per object (keyed by its id, which must be stable over frames: a ground-truth or track id):
//   - errors per parameter from the KpiModel (conditioned on class, range bin, visibility
//     bin), AR(1) in time with heavy-tailed innovations, size errors mostly a per-track
//     constant; position errors along/across the line of sight;
//   - misses from a two-state Markov chain whose stationary rate is 1 - detection probability
//     (range, visibility, plus the class's optional detection conditional term, clamped to
//     [0, 1]) and whose miss runs last miss_burst_mean frames on average;
//   - 180-degree heading flips from a second chain (heading_flip_probability, flip_burst_mean);
//   - a score drawn from the class's score quantiles;
//   - optional conditional terms (kpi_model.h ConditionalTerm): a bias and sigma scale per bin
//     of a feature computed from the truth object (and, for track_age, the id's state); a term
//     with relative_to multiplies its bias by that feature of the same object;
// and per frame a Poisson number of false positives per class (with the class's optional fp_table:
// per bin of the table its own Poisson count, placed by the bin's quantiles; with the class's optional
// fp_persistence last frame's false positives survive, keeping their id, and births come at the rate x
// (1 - survival)). A feedback controller per
// class and parameter keeps the running mean and spread of the injected standardized noise on
// target (0, 1), so the injected errors keep the model's mean and std per bin.
// Random draws: each track owns one stream per error parameter and one each for its misses,
// flips and scores, keyed by (seed, id, first frame, purpose), and each class's false
// positives one stream; so a model change on one target or class does not move the draws of
// another (common random numbers when two models are compared with one seed).
// Per-frame work allocates nothing once the per-object tables have grown.
#include <array>
#include <cstdint>
#include <string>
#include <unordered_map>
#include <vector>

#include "sensor/kpi_model.h"
#include "sensor/kpi_noise.h"
#include "sensor/scene.h"

namespace lidarsim::sensor {

struct KpiInjection {
  int id = -1;               // object id
  int truth_index = -1;      // index in this frame's input
  bool modelled = false;     // false: class has no model, passed through unchanged
  bool detected = true;
  bool flipped = false;
  int range_bin = 0, visibility_bin = 0;
  double detection_probability = 1;  // the stationary detection probability used (1 if not modelled)
  std::array<double, kNumKpiParams> error{};  // injected error per parameter (reported - truth)
};

struct KpiOptions {
  bool noise = true;
  bool misses = true;
  bool false_positives = true;
  bool flips = true;
  int forget_after_frames = 100;  // drop the noise state of ids absent this long
};

// A conditional term's feature (kConditionalFeatures) for a truth object in the sensor frame with
// BEV range `range`, `track_age` frames after its first; names and definitions as in the object
// loop's vocabulary (qualify/objects/objects.h). Throws lidarsim::Error for any other name.
double conditional_feature(const std::string& name, const Object& o, double range, long track_age);

class KpiManager {
 public:
  explicit KpiManager(KpiModel model, std::uint64_t seed = 1, KpiOptions options = {});

  // One frame. `truth` in the sensor frame (range and line of sight are taken from the
  // sensor origin), visible_fraction set. `reported` is cleared and receives the detected
  // objects (same id as their truth) followed by false positives (ids <= -1000).
  void apply(const std::vector<Object>& truth, std::vector<Object>& reported);

  // The sensor's motion since the previous apply() (translation in the previous frame's sensor frame,
  // m, and yaw, rad), for the next apply() only: persistent false positives (ClassModel::fp_persistence)
  // are moved by its inverse, so they stay put in the world as KITTI's ghosts do. Not called: they
  // stay put in the sensor frame.
  void set_ego_motion(const Eigen::Vector2d& translation, double yaw);

  const std::vector<KpiInjection>& injections() const { return injections_; }
  // The stationary detection probability apply() uses for this truth object (sensor frame,
  // visible_fraction set) at `track_age` frames after its first frame: the model's
  // [range bin][visibility bin] entry plus the class's detection conditional term, clamped to
  // [0, 1]; 1 for a class without a model. No state is read or changed.
  double detection_probability(const Object& o, long track_age = 0) const;
  const KpiModel& model() const { return model_; }
  const RunningTargetController& controller(ObjectClass cls, KpiParam p) const;
  long frame() const { return frame_; }

 private:
  struct TrackState {
    std::array<double, kNumKpiParams> z{};      // AR(1) states
    std::array<double, kNumKpiParams> c{};      // per-track constants
    BurstChain miss, flip;
    std::array<KpiRng, kNumKpiParams> error_rng;
    KpiRng miss_rng, flip_rng, score_rng;
    long last_frame = -1;
    long first_frame = -1;  // for the track_age feature of conditional terms
  };
  TrackState& state_for(int id);
  void forget_stale();
  // A persistent false positive (ClassModel::fp_persistence), kept from frame to frame.
  struct Ghost {
    int id = 0;
    double x = 0, y = 0, heading = 0;
    double score_z = 0;                         // normal score of its score
    const std::vector<double>* score_q = nullptr;  // the score quantiles it was born with (in model_)
  };
  static double quantile_at(const std::vector<double>& q, double fallback, double u);
  // The steps of apply(): a modelled truth object (its track state, errors, miss, flip and, when
  // detected, the reported object); the false positives of class k (its persistent ones first,
  // then the births).
  void report_modelled(const Object& o, int slot, KpiInjection& inj, std::vector<Object>& reported);
  TrackState& advance_track(const Object& o, bool& fresh, int& gap);
  void draw_errors(const Object& o, int slot, double range, TrackState& st, bool fresh, int gap, KpiInjection& inj);
  struct Births {
    double factor = 1;       // the births' share of the stationary rate
    double ghost_share = 1;  // the share of births that become ghosts
  };
  void false_positives_of_class(int k, const ClassModel& cm, std::vector<Object>& reported);
  Births carry_ghosts(int k, const ClassModel& cm, std::vector<Object>& reported);
  void birth_false_positives(int k, const ClassModel& cm, const Births& births, double rate,
                             const std::vector<double>& range_q, const std::vector<double>& azimuth_q,
                             const std::vector<double>& score_q, std::vector<Object>& reported);
  static void emit_false_positive(int k, const ClassModel& cm, const Ghost& g, double score,
                                  std::vector<Object>& reported);
  static void emit_ghost(int k, const ClassModel& cm, const Ghost& g, std::vector<Object>& reported);

  static double sample_quantiles(const std::vector<double>& q, double fallback, KpiRng& rng);
  double detection_probability(int slot, int rb, int vb, const Object& o, double range, long track_age) const;

  KpiModel model_;
  KpiOptions options_;
  std::uint64_t seed_;
  std::array<KpiRng, kNumObjectClasses> fp_rng_;  // per class
  std::array<int, kNumObjectClasses> class_slot_{};                // ObjectClass -> slot in class_models_, -1 none
  std::vector<const ClassModel*> class_models_;
  std::vector<RunningTargetController> controllers_;  // slot * kNumKpiParams + param
  // Per slot * kNumKpiParams + param, worked out once: the innovation's constants,
  // sqrt(1 - ar1^2) and the conditional term's feature (-1 none).
  std::vector<InnovationSampler> samplers_;
  std::vector<double> ar1_root_;
  std::vector<int> error_feature_;
  std::vector<int> error_relative_;     // the term's relative_to feature (-1: an absolute bias)
  std::vector<int> detection_feature_;  // per slot
  std::array<bool, kNumObjectClasses> fp_own_model_{};  // the class has its own model (false positives drawn once per model)
  std::unordered_map<int, int> slot_of_id_;
  std::vector<TrackState> states_;
  std::vector<int> free_states_;
  std::vector<KpiInjection> injections_;
  std::array<std::vector<Ghost>, kNumObjectClasses> ghosts_;  // per class
  std::array<bool, kNumObjectClasses> fp_started_{};
  Eigen::Vector2d ego_xy_ = Eigen::Vector2d::Zero();
  double ego_yaw_ = 0;
  long frame_ = 0;
  int next_fp_id_ = -1000;
};

}  // namespace lidarsim::sensor
