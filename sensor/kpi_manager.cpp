#include "sensor/kpi_manager.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include "common/error.h"

namespace lidarsim::sensor {

namespace {
// Stream purposes (KpiRng::stream); error parameters use 0 .. kNumKpiParams - 1.
constexpr std::uint64_t kPurposeMiss = 16, kPurposeFlip = 17, kPurposeScore = 18, kPurposeFalsePositives = 32;
constexpr std::uint64_t kFalsePositiveKey = ~std::uint64_t{0};  // no track id takes this value
const std::vector<double> kNone;  // a table bin without quantiles of its own
}  // namespace

namespace {
double wrap_angle(double a) {
  constexpr double pi = std::numbers::pi;
  a += pi;
  // fmod is exact and leaves |a| < 2 pi as it is: call it only for the rest.
  if (!(std::abs(a) < 2 * pi)) a = std::fmod(a, 2 * pi);
  if (a < 0) a += 2 * pi;
  return a - pi;
}
}  // namespace

namespace {

// kConditionalFeatures as numbers, so a frame compares no strings (resolved once per model).
enum class Feature {
  Range, Azimuth, Speed, RadialVelocity, LongitudinalVelocity, LateralVelocity, Acceleration, Size, BoxWidth,
  BoxHeight, HeadingToLineOfSight, Truncation, Visibility, TrackAge, Unknown
};

Feature feature_of(const std::string& name) {
  static const std::pair<const char*, Feature> names[] = {
      {"range", Feature::Range}, {"azimuth", Feature::Azimuth}, {"speed", Feature::Speed},
      {"radial_velocity", Feature::RadialVelocity}, {"longitudinal_velocity", Feature::LongitudinalVelocity},
      {"lateral_velocity", Feature::LateralVelocity}, {"acceleration", Feature::Acceleration},
      {"size", Feature::Size}, {"box_width", Feature::BoxWidth}, {"box_height", Feature::BoxHeight},
      {"heading_to_line_of_sight", Feature::HeadingToLineOfSight}, {"truncation", Feature::Truncation},
      {"visibility", Feature::Visibility}, {"track_age", Feature::TrackAge}};
  for (const auto& [n, f] : names)
    if (name == n) return f;
  return Feature::Unknown;
}

// Only what the feature needs is computed (the azimuth and heading's cos / sin for the few that use them).
double feature_value(Feature f, const Object& o, double range, long track_age) {
  switch (f) {
    case Feature::Range: return range;
    case Feature::Azimuth: return std::atan2(o.position.y(), o.position.x());
    case Feature::Speed: return o.velocity.head<2>().norm();  // BEV, as the loop computes it
    case Feature::RadialVelocity: {
      const Eigen::Vector2d v = o.velocity.head<2>();
      return range > 1e-6 ? v.dot(o.position.head<2>() / range) : 0.0;
    }
    case Feature::LongitudinalVelocity: {
      const Eigen::Vector2d v = o.velocity.head<2>();
      const Eigen::Vector2d h(std::cos(o.heading), std::sin(o.heading));
      return v.dot(h);
    }
    case Feature::LateralVelocity: {
      const Eigen::Vector2d v = o.velocity.head<2>();
      const Eigen::Vector2d h(std::cos(o.heading), std::sin(o.heading));
      return -h.y() * v.x() + h.x() * v.y();
    }
    case Feature::Acceleration: return o.acceleration.head<2>().norm();  // BEV, as the loop computes it
    case Feature::Size: return o.size.x();
    case Feature::BoxWidth: return o.size.y();
    case Feature::BoxHeight: return o.size.z();
    case Feature::HeadingToLineOfSight: {
      const double azimuth = std::atan2(o.position.y(), o.position.x());
      const double a = std::abs(wrap_angle(o.heading - azimuth));  // [0, pi]
      return a > std::numbers::pi / 2 ? std::numbers::pi - a : a;
    }
    case Feature::Truncation: return o.truncation;
    case Feature::Visibility: return o.visible_fraction;
    case Feature::TrackAge: return static_cast<double>(track_age);
    case Feature::Unknown: break;
  }
  return 0;
}

}  // namespace

KpiManager::KpiManager(KpiModel model, std::uint64_t seed, KpiOptions options)
    : model_(std::move(model)), options_(options), seed_(seed) {
  model_.validate();
  class_slot_.fill(-1);
  for (int k = 0; k < kNumObjectClasses; ++k) {
    const ClassModel* m = model_.find(static_cast<ObjectClass>(k));
    if (!m) continue;
    const auto it = std::find(class_models_.begin(), class_models_.end(), m);
    class_slot_[k] = static_cast<int>(it - class_models_.begin());
    if (it == class_models_.end()) class_models_.push_back(m);
  }
  for (int k = 0; k < kNumObjectClasses; ++k) fp_rng_[k] = KpiRng::stream(seed_, kFalsePositiveKey, k, kPurposeFalsePositives);
  controllers_.assign(class_models_.size() * kNumKpiParams, RunningTargetController(model_.controller));
  for (const ClassModel* cm : class_models_) {
    for (const ErrorModel& em : cm->errors) {
      samplers_.emplace_back(em.innovation);
      ar1_root_.push_back(std::sqrt(std::max(0.0, 1 - em.ar1 * em.ar1)));  // as ar1_step computes it
      error_feature_.push_back(em.conditional.present() ? static_cast<int>(feature_of(em.conditional.feature)) : -1);
      error_relative_.push_back(em.conditional.present() && !em.conditional.relative_to.empty()
                                    ? static_cast<int>(feature_of(em.conditional.relative_to))
                                    : -1);
    }
    detection_feature_.push_back(
        cm->detection_conditional.present() ? static_cast<int>(feature_of(cm->detection_conditional.feature)) : -1);
  }
  for (int k = 0; k < kNumObjectClasses; ++k) fp_own_model_[k] = model_.classes.count(kpi_class_name(static_cast<ObjectClass>(k))) > 0;
}

const RunningTargetController& KpiManager::controller(ObjectClass cls, KpiParam p) const {
  const int slot = class_slot_[static_cast<int>(cls)];
  if (slot < 0) throw Error(std::string("kpi manager: no model for class ") + kpi_class_name(cls));
  return controllers_[slot * kNumKpiParams + static_cast<int>(p)];
}

KpiManager::TrackState& KpiManager::state_for(int id) {
  const auto it = slot_of_id_.find(id);
  if (it != slot_of_id_.end()) return states_[it->second];
  int slot;
  if (!free_states_.empty()) {
    slot = free_states_.back();
    free_states_.pop_back();
    states_[slot] = TrackState{};
  } else {
    slot = static_cast<int>(states_.size());
    states_.emplace_back();
  }
  slot_of_id_.emplace(id, slot);
  return states_[slot];
}

void KpiManager::forget_stale() {
  for (auto it = slot_of_id_.begin(); it != slot_of_id_.end();) {
    if (frame_ - states_[it->second].last_frame > options_.forget_after_frames) {
      free_states_.push_back(it->second);
      it = slot_of_id_.erase(it);
    } else {
      ++it;
    }
  }
}

double KpiManager::sample_quantiles(const std::vector<double>& q, double fallback, KpiRng& rng) {
  if (q.size() < 2) return fallback;
  return quantile_at(q, fallback, kpi_uniform(rng));
}

double KpiManager::quantile_at(const std::vector<double>& q, double fallback, double u) {
  if (q.size() < 2) return fallback;
  const double x = u * static_cast<double>(q.size() - 1);
  const size_t i = std::min(static_cast<size_t>(x), q.size() - 2);
  const double f = x - static_cast<double>(i);
  return q[i] + f * (q[i + 1] - q[i]);
}


double conditional_feature(const std::string& name, const Object& o, double range, long track_age) {
  const Feature f = feature_of(name);
  // Not in kConditionalFeatures (a validated model names none such): a programming error.
  if (f == Feature::Unknown) throw Error("kpi manager: conditional feature \"" + name + "\" cannot be computed");
  return feature_value(f, o, range, track_age);
}


double KpiManager::detection_probability(int slot, int rb, int vb, const Object& o, double range,
                                         long track_age) const {
  const ClassModel& cm = *class_models_[slot];
  double p = cm.detection_probability[rb][vb];
  if (detection_feature_[slot] >= 0) {
    const auto f = static_cast<Feature>(detection_feature_[slot]);
    const ConditionalTerm& ct = cm.detection_conditional;
    const int b = ct.bin(feature_value(f, o, range, track_age));
    p = (ct.scale.empty() ? p : p * ct.scale[b]) + ct.bias[b];
  }
  return std::clamp(p, 0.0, 1.0);
}

double KpiManager::detection_probability(const Object& o, long track_age) const {
  const int slot = class_slot_[static_cast<int>(o.cls)];
  if (slot < 0) return 1;
  const double range = o.position.head<2>().norm();
  return detection_probability(slot, model_.range_bin(range), model_.visibility_bin(o.visible_fraction),
                               o, range, track_age);
}

void KpiManager::set_ego_motion(const Eigen::Vector2d& translation, double yaw) {
  ego_xy_ = translation;
  ego_yaw_ = yaw;
}

namespace {

void check_finite(const Object& o) {
  if (!o.position.allFinite() || !o.velocity.allFinite() || !o.size.allFinite() || !std::isfinite(o.heading))
    throw Error("kpi manager: object " + std::to_string(o.id) + ": position/velocity/size/heading: must be finite");
  if (!std::isfinite(o.visible_fraction))
    throw Error("kpi manager: object " + std::to_string(o.id) + ": visible_fraction: must be finite");
  if (!o.acceleration.allFinite() || !std::isfinite(o.truncation))
    throw Error("kpi manager: object " + std::to_string(o.id) + ": acceleration/truncation: must be finite");
}

// The reported object: the truth moved by the injected errors (position and velocity along and
// across the line of sight u), its size, its heading (flipped by pi when flipped).
void perturb(Object& r, const KpiInjection& inj, const Eigen::Vector2d& u) {
  const Eigen::Vector2d left(-u.y(), u.x());
  const auto& e = inj.error;
  r.position.head<2>() += e[int(KpiParam::PositionAlong)] * u + e[int(KpiParam::PositionAcross)] * left;
  r.position.z() += e[int(KpiParam::PositionVertical)];
  r.velocity.head<2>() += e[int(KpiParam::VelocityAlong)] * u + e[int(KpiParam::VelocityAcross)] * left;
  r.size.x() = std::max(0.05, r.size.x() + e[int(KpiParam::Length)]);
  r.size.y() = std::max(0.05, r.size.y() + e[int(KpiParam::Width)]);
  r.size.z() = std::max(0.05, r.size.z() + e[int(KpiParam::Height)]);
  r.heading = wrap_angle(r.heading + e[int(KpiParam::Heading)] + (inj.flipped ? std::numbers::pi : 0.0));
}

}  // namespace

void KpiManager::apply(const std::vector<Object>& truth, std::vector<Object>& reported) {
  ++frame_;
  reported.clear();
  injections_.resize(truth.size());
  for (size_t i = 0; i < truth.size(); ++i) {
    const Object& o = truth[i];
    KpiInjection& inj = injections_[i];
    inj = KpiInjection{};
    inj.id = o.id;
    inj.truth_index = static_cast<int>(i);
    const int slot = class_slot_[static_cast<int>(o.cls)];
    if (slot < 0) {  // no model for this class: reported as it is
      reported.push_back(o);
      continue;
    }
    check_finite(o);
    report_modelled(o, slot, inj, reported);
  }
  if (options_.false_positives)
    for (int k = 0; k < kNumObjectClasses; ++k) {
      const int slot = class_slot_[k];
      // Each model once, under its own class (not again for the classes that fall back to it).
      if (slot >= 0 && fp_own_model_[k]) false_positives_of_class(k, *class_models_[slot], reported);
    }
  ego_xy_.setZero();
  ego_yaw_ = 0;
  if (frame_ % 64 == 0) forget_stale();
}

KpiManager::TrackState& KpiManager::advance_track(const Object& o, bool& fresh, int& gap) {
  TrackState& st = state_for(o.id);
  fresh = st.last_frame < 0;
  gap = fresh ? 1 : static_cast<int>(std::min<long>(frame_ - st.last_frame, 1000));
  st.last_frame = frame_;
  if (fresh) {
    st.first_frame = frame_;
    const auto id = static_cast<std::uint64_t>(static_cast<std::int64_t>(o.id));
    const auto ff = static_cast<std::uint64_t>(frame_);
    for (int p = 0; p < kNumKpiParams; ++p) st.error_rng[p] = KpiRng::stream(seed_, id, ff, p);
    st.miss_rng = KpiRng::stream(seed_, id, ff, kPurposeMiss);
    st.flip_rng = KpiRng::stream(seed_, id, ff, kPurposeFlip);
    st.score_rng = KpiRng::stream(seed_, id, ff, kPurposeScore);
  }
  if (gap == 0) throw Error("kpi manager: object id " + std::to_string(o.id) + " appears twice in one frame");
  return st;
}

void KpiManager::report_modelled(const Object& o, int slot, KpiInjection& inj, std::vector<Object>& reported) {
  const ClassModel& cm = *class_models_[slot];
  inj.modelled = true;
  const Eigen::Vector2d bev = o.position.head<2>();
  const double range = bev.norm();
  const int rb = model_.range_bin(range), vb = model_.visibility_bin(o.visible_fraction);
  inj.range_bin = rb;
  inj.visibility_bin = vb;
  bool fresh = false;
  int gap = 1;
  TrackState& st = advance_track(o, fresh, gap);
  draw_errors(o, slot, range, st, fresh, gap, inj);
  const double pd = detection_probability(slot, rb, vb, o, range, frame_ - st.first_frame);
  inj.detection_probability = pd;
  const bool missed = st.miss.step(1 - pd, cm.miss_burst_mean, st.miss_rng);
  const bool flipped = st.flip.step(cm.heading_flip_probability, cm.flip_burst_mean, st.flip_rng);
  inj.detected = !(options_.misses && missed);
  inj.flipped = options_.flips && flipped;
  if (!inj.detected) return;

  reported.push_back(o);
  Object& r = reported.back();
  perturb(r, inj, range > 1e-6 ? Eigen::Vector2d(bev / range) : Eigen::Vector2d(1, 0));
  r.score = sample_quantiles(cm.score_quantiles, 1.0, st.score_rng);
}

void KpiManager::draw_errors(const Object& o, int slot, double range, TrackState& st, bool fresh, int gap,
                             KpiInjection& inj) {
  const ClassModel& cm = *class_models_[slot];
  const int rb = inj.range_bin, vb = inj.visibility_bin;
  // Every parameter's AR(1) state advances, even when the object will be missed.
  const int first = slot * kNumKpiParams;
  for (int p = 0; p < kNumKpiParams; ++p) {
    const ErrorModel& em = cm.errors[p];
    KpiRng& rng = st.error_rng[p];
    const double eps = samplers_[first + p](rng);
    if (fresh) {
      st.z[p] = eps;  // stationary start
      st.c[p] = kpi_normal(rng);
    } else {
      st.z[p] = gap == 1 ? ar1_step_1(st.z[p], em.ar1, ar1_root_[first + p], eps) : ar1_step(st.z[p], em.ar1, gap, eps);
    }
    const double z = controllers_[first + p].apply(st.z[p]);
    double bias = 0, scale = 1;
    if (error_feature_[first + p] >= 0) {
      const auto f = static_cast<Feature>(error_feature_[first + p]);
      const int b = em.conditional.bin(feature_value(f, o, range, frame_ - st.first_frame));
      bias = em.conditional.bias[b];
      if (error_relative_[first + p] >= 0)
        bias *= feature_value(static_cast<Feature>(error_relative_[first + p]), o, range, frame_ - st.first_frame);
      if (!em.conditional.scale.empty()) scale = em.conditional.scale[b];
    }
    inj.error[p] = options_.noise ? em.mean[rb] + bias + em.sigma[rb] * scale * em.visibility_std_scale[vb] * z +
                                        em.track_std * st.c[p]
                                  : 0.0;
  }
}

void KpiManager::emit_false_positive(int k, const ClassModel& cm, const Ghost& g, double score,
                                     std::vector<Object>& reported) {
  Object fp;
  fp.id = g.id;
  fp.cls = static_cast<ObjectClass>(k);
  fp.position = Eigen::Vector3d(g.x, g.y, cm.fp_z);
  fp.size = cm.mean_size;
  fp.heading = g.heading;
  fp.visible_fraction = 1;
  fp.score = score;
  reported.push_back(fp);
}

void KpiManager::emit_ghost(int k, const ClassModel& cm, const Ghost& g, std::vector<Object>& reported) {
  emit_false_positive(k, cm, g,
                      quantile_at(g.score_q ? *g.score_q : kNone, 0.5, 0.5 * std::erfc(-g.score_z / std::numbers::sqrt2)),
                      reported);
}

KpiManager::Births KpiManager::carry_ghosts(int k, const ClassModel& cm, std::vector<Object>& reported) {
  const FalsePositivePersistence& pers = cm.fp_persistence;
  KpiRng& rng = fp_rng_[k];
  std::vector<Ghost>& ghosts = ghosts_[k];
  const double c = std::cos(ego_yaw_), s = std::sin(ego_yaw_);
  const double root = std::sqrt(std::max(0.0, 1 - pers.score_ar1 * pers.score_ar1));
  size_t kept = 0;
  for (Ghost& g : ghosts) {
    if (!(kpi_uniform(rng) < pers.survival)) continue;
    // Into this frame's sensor frame: the ghost stays put in the world.
    const double dx = g.x - ego_xy_.x(), dy = g.y - ego_xy_.y();
    g.x = c * dx + s * dy, g.y = -s * dx + c * dy;
    g.heading = wrap_angle(g.heading - ego_yaw_);
    if (pers.jitter > 0) {
      g.x += pers.jitter * kpi_normal(rng);
      g.y += pers.jitter * kpi_normal(rng);
    }
    g.score_z = pers.score_ar1 * g.score_z + root * kpi_normal(rng);
    emit_ghost(k, cm, g, reported);
    ghosts[kept++] = g;
  }
  ghosts.resize(kept);
  // Births: one-frame false positives at rate x (1 - g) and ghosts at rate x g x (1 - survival); the
  // first frame starts from the stationary count (Poisson with the full rate, a share g ghosts).
  const double g = pers.ghost_share;
  Births births;
  births.factor = fp_started_[k] ? (1 - g) + g * (1 - pers.survival) : 1;
  births.ghost_share = fp_started_[k] ? g * (1 - pers.survival) / births.factor : g;
  fp_started_[k] = true;
  return births;
}

void KpiManager::birth_false_positives(int k, const ClassModel& cm, const Births& births, double rate,
                                       const std::vector<double>& rq, const std::vector<double>& aq,
                                       const std::vector<double>& sq, std::vector<Object>& reported) {
  const bool persistent = cm.fp_persistence.present();
  KpiRng& rng = fp_rng_[k];
  std::poisson_distribution<int> poisson(rate * births.factor);
  const int n = poisson(rng);
  for (int f = 0; f < n; ++f) {
    Ghost g;
    g.id = next_fp_id_--;
    if (next_fp_id_ < -1000000000) next_fp_id_ = -1000;
    const double rr = sample_quantiles(rq.empty() ? cm.fp_range_quantiles : rq, 20, rng),
                 az = sample_quantiles(aq.empty() ? cm.fp_azimuth_quantiles : aq, 0, rng);
    g.x = rr * std::cos(az), g.y = rr * std::sin(az);
    std::uniform_real_distribution<double> h(-std::numbers::pi, std::numbers::pi);
    g.heading = h(rng);
    const std::vector<double>& q = sq.empty() ? cm.fp_score_quantiles : sq;
    if (!persistent) {
      // One uniform through the quantiles: a model without persistence draws its stream this way.
      emit_false_positive(k, cm, g, sample_quantiles(q, 0.5, rng), reported);
      continue;
    }
    // A normal score, so its AR(1) over the ghost's life keeps the quantiles' distribution.
    g.score_z = kpi_normal(rng);
    g.score_q = &q;
    emit_ghost(k, cm, g, reported);
    // A ghost, or one frame only (a draw only when some births last one frame).
    if (births.ghost_share >= 1 || kpi_uniform(rng) < births.ghost_share) ghosts_[k].push_back(g);
  }
}

void KpiManager::false_positives_of_class(int k, const ClassModel& cm, std::vector<Object>& reported) {
  const FalsePositiveTable& table = cm.fp_table;
  // Persistence: last frame's false positives first, each surviving with its own draw. Without
  // the field no draw is spent on ghosts, so such a model's stream is that of births alone.
  Births births;
  if (cm.fp_persistence.present())
    births = carry_ghosts(k, cm, reported);
  else
    ghosts_[k].clear();
  if (table.present() ? table.total_rate() <= 0 : cm.false_positive_rate <= 0) return;
  if (!table.present()) {
    birth_false_positives(k, cm, births, cm.false_positive_rate, {}, {}, {}, reported);
    return;
  }
  // A table: each bin its own Poisson count, placed by the bin's quantiles.
  auto at = [](const std::vector<std::vector<double>>& q, size_t b) -> const std::vector<double>& {
    return q.empty() ? kNone : q[b];
  };
  for (size_t b = 0; b < table.rate.size(); ++b)
    if (table.rate[b] > 0)
      birth_false_positives(k, cm, births, table.rate[b], at(table.range_quantiles, b), at(table.azimuth_quantiles, b),
                            at(table.score_quantiles, b), reported);
}

}  // namespace lidarsim::sensor
