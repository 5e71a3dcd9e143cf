#pragma once
// The KPI manager's error model: what a real detector gets wrong, per class and parameter,
// conditioned on range bin and visibility bin. Stored as JSON (nlohmann-json); fitted from
// KITTI tracking ground truth vs PointRCNN detections by `lidar-calibrate`
// (data/models/kpi_pointrcnn.json is the shipped default).
//
// One parameter's error at frame t for track k, in range bin r and visibility bin v:
//   e = mean[r] + sigma[r] * visibility_std_scale[v] * z_t + track_std * c_k
// z_t: unit-variance AR(1), z_t = ar1 z_{t-1} + sqrt(1 - ar1^2) eps_t, eps_t from a heavy-tailed
// unit-variance innovation (Gaussian, Student-t, or a two-scale Gaussian mixture);
// c_k: a per-track constant ~ N(0, 1) (size errors are nearly constant along a track).
#include <array>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "sensor/scene.h"

namespace lidarsim::sensor {

// The classes the KPI model is fitted for and the object loop judges (KITTI tracking's evaluated
// classes), in the order of every table indexed by class (0 Car, 1 Pedestrian, 2 Cyclist).
inline constexpr int kModelledClassCount = 3;
inline const std::array<std::string, kModelledClassCount> kModelledClasses = {"Car", "Pedestrian", "Cyclist"};

enum class KpiParam {
  PositionAlong,    // along the line of sight (radial), m
  PositionAcross,   // across the line of sight (left of it), m
  PositionVertical, // z, m
  VelocityAlong,    // m/s
  VelocityAcross,   // m/s
  Length,           // m
  Width,            // m
  Height,           // m
  Heading,          // rad, excluding 180-degree flips (modelled separately)
};
inline constexpr int kNumKpiParams = 9;
const char* to_string(KpiParam p);

struct Innovation {
  enum class Type { Gaussian, StudentT, Mixture };
  Type type = Type::Gaussian;
  double dof = 0;                  // Student-t degrees of freedom (> 2)
  double outlier_probability = 0;  // mixture: weight of the wide component
  double outlier_scale = 1;        // mixture: sigma_wide / sigma_core (> 1)
  double excess_kurtosis() const;  // of the unit-variance innovation (inf for t with dof <= 4)
};

// Optional conditional term (an effect the object loop can add): in the bin of a
// per-object feature, `bias` is added to the error's mean and `scale` multiplies its sigma.
// Feature names are the object loop's vocabulary (qualify/objects/objects.h) that the KPI manager can
// compute from a truth object: kConditionalFeatures. The same shape serves as the class's
// conditional term on detection probability (ClassModel::detection_conditional): there `scale`
// (optional, >= 0) multiplies the cell's probability (a gain: a dropout that removes a share of
// detections wherever the cell's probability stands) and `bias` is then added (clamped to [0, 1]).
// On an error, `relative_to` (optional, a kConditionalFeatures name) makes the bias relative: the
// bin's bias times that feature of the same object, e.g. a length error that is a share of the
// object's own length (relative_to "size"): a size error that scales with the size is common in
// real detectors, and a bias per bin can only hold the class's mean share x its mean size.
struct ConditionalTerm {
  std::string feature;        // empty: no term (the file has no "conditional")
  std::vector<double> edges;  // lower bin edges, increasing; values below edges[0] use bin 0
  std::vector<double> bias;   // per bin
  std::vector<double> scale;  // per bin, > 0; empty: 1 everywhere
  std::string relative_to = {};  // errors only; empty: the bias as it is (the file has no "relative_to")
  bool present() const { return !feature.empty(); }
  int bin(double value) const;
};
inline const std::vector<std::string> kConditionalFeatures = {
    "range", "azimuth", "speed", "radial_velocity", "lateral_velocity", "longitudinal_velocity",
    "acceleration", "size", "box_width", "box_height", "heading_to_line_of_sight", "truncation", "visibility",
    "track_age"};

// Optional false-positive table of a class ("fp_table" in the file; the object loop's
// false-positive effect): the class's false positives as a table over bins of one of their own
// attributes (kFalsePositiveFeatures), each bin with its own Poisson rate per frame and its own
// quantiles of range, azimuth and score to place its false positives by (an empty entry: the
// class's fp_*_quantiles). When present it replaces false_positive_rate and the class quantiles in
// the KPI manager: independent range and azimuth quantiles cannot hold a hot spot (false detections
// in a window of azimuth at one range), a table over azimuth with per-bin range quantiles can.
struct FalsePositiveTable {
  std::string feature;        // empty: no table (the file has no "fp_table")
  std::vector<double> edges;  // lower bin edges, increasing; values below edges[0] use bin 0
  std::vector<double> rate;   // per bin, false positives per frame, >= 0
  std::vector<std::vector<double>> range_quantiles, azimuth_quantiles, score_quantiles;  // per bin, or empty
  bool present() const { return !feature.empty(); }
  int bin(double value) const;
  double total_rate() const;
};
inline const std::vector<std::string> kFalsePositiveFeatures = {"range", "azimuth", "score"};

// Optional persistence of a class's false positives ("fp_persistence" in the file): on KITTI
// 36 % of PointRCNN's false positives have one of the same class within 1.5 m in the previous frame
// (ghost tracks), while most others last one frame. A share `ghost_share` of the false positives are
// ghosts: reported again the next frame with probability `survival` (a geometric lifetime, mean
// 1 / (1 - survival) frames), with the same id, class, box and heading, moved by `jitter` (m, per axis
// per frame), their score's normal score an AR(1) with `score_ar1` (so the score quantiles hold); the
// rest last one frame. Births of ghosts come at rate x ghost_share x (1 - survival), so the mean count
// per frame stays the class's rate (the first frame starts from the stationary count). Ghosts live in
// the sensor frame unless the caller gives the ego motion (KpiManager::set_ego_motion): measured on
// KITTI they stay put in the world (they move backwards with the ego speed in the sensor frame).
struct FalsePositivePersistence {
  double survival = 0;     // [0, 0.999]; 0: no persistence (the file has no "fp_persistence")
  double ghost_share = 1;  // (0, 1]: share of the false positives (per frame) that are ghosts
  double jitter = 0;       // m, >= 0
  double score_ar1 = 0;    // [0, 1]; 0: a fresh score each frame, 1: the score kept
  bool present() const { return survival > 0; }
};

struct ErrorModel {
  std::vector<double> mean;                  // per range bin
  std::vector<double> sigma;                 // per range bin, >= 0 ("std" in the file)
  std::vector<double> visibility_std_scale;  // per visibility bin, > 0
  double ar1 = 0;                            // lag-1 autocorrelation of z, in (-1, 1)
  double track_std = 0;                      // per-track constant component, >= 0
  Innovation innovation;
  ConditionalTerm conditional;               // optional
};

struct ClassModel {
  std::array<ErrorModel, kNumKpiParams> errors;
  std::vector<std::vector<double>> detection_probability;  // [range bin][visibility bin]
  // Optional ("detection_conditional" in the file): p = clamp(detection_probability[r][v] x
  // scale[bin of feature] + bias[bin], 0, 1); bias per bin in [-1, 1], scale >= 0 (empty: 1).
  ConditionalTerm detection_conditional;
  double miss_burst_mean = 1;       // mean length of a run of misses, frames (>= 1)
  double heading_flip_probability = 0;
  double flip_burst_mean = 1;       // mean length of a run of flipped frames (>= 1)
  std::vector<double> score_quantiles;  // true positives: scores at probabilities 0, 1/(n-1), ..., 1
  // False positives: a Poisson number per frame, placed by range/azimuth quantiles.
  double false_positive_rate = 0;   // per frame
  std::vector<double> fp_range_quantiles;    // m
  std::vector<double> fp_azimuth_quantiles;  // rad, atan2(y, x)
  std::vector<double> fp_score_quantiles;
  double fp_z = -0.9;               // m, box centre height in the sensor frame
  FalsePositiveTable fp_table;      // optional; replaces the rate and quantiles above when present
  FalsePositivePersistence fp_persistence;  // optional; absent: a fresh set of false positives every frame
  Eigen::Vector3d mean_size = Eigen::Vector3d(4, 1.8, 1.5);
};

struct ControllerConfig {
  bool enabled = true;
  double window = 500;       // samples in the running (exponentially weighted) statistics
  double mean_gain = 0.0005; // integral gain on the running mean, per sample (critically damped with window 500)
  double std_gain = 0.0005;  // multiplicative gain on the running std, per sample
};

struct KpiModel {
  std::string source;                          // free text: what it was fitted on
  std::vector<double> range_bin_edges;         // lower edges, ascending from 0; last bin open
  std::vector<double> visibility_bin_edges;    // lower edges, ascending from 0, within [0, 1]
  std::map<std::string, ClassModel> classes;   // "Car", "Pedestrian", "Cyclist", ...
  ControllerConfig controller;

  int range_bins() const { return static_cast<int>(range_bin_edges.size()); }
  int visibility_bins() const { return static_cast<int>(visibility_bin_edges.size()); }
  int range_bin(double range) const;
  int visibility_bin(double visible_fraction) const;
  // The class model used for an object class: its own, else a fallback (Van, Truck, Bus, Misc
  // -> Car; Motorcycle -> Cyclist), else nullptr (objects of that class pass through unchanged).
  const ClassModel* find(ObjectClass cls) const;
  // Throws lidarsim::Error "<file>: <field>: <what was expected>".
  void validate(const std::string& file = "kpi model") const;
};

// Model class name used in files: the ObjectClass names of scene.h.
std::string kpi_class_name(ObjectClass cls);

KpiModel load_kpi_model(const std::filesystem::path& path);  // validates; throws lidarsim::Error
KpiModel parse_kpi_model(const std::string& json_text, const std::string& file_name);
std::string kpi_model_to_json(const KpiModel& model);
void save_kpi_model(const KpiModel& model, const std::filesystem::path& path);  // atomic

// A small hand-set model (no fit), for tests and when no file is given.
KpiModel default_kpi_model();

}  // namespace lidarsim::sensor
