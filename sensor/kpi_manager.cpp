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
}  // namespace

KpiManager::KpiManager(KpiModel model, std::uint64_t seed, KpiOptions options)
    : model_(std::move(model)), options_(options), seed_(seed) {
  model_.validate();
  class_slot_.fill(-1);
  for (int k = 0; k < 8; ++k) {
    const ClassModel* m = model_.find(static_cast<ObjectClass>(k));
    if (!m) continue;
    const auto it = std::find(class_models_.begin(), class_models_.end(), m);
    class_slot_[k] = static_cast<int>(it - class_models_.begin());
    if (it == class_models_.end()) class_models_.push_back(m);
  }
  for (int k = 0; k < 8; ++k) fp_rng_[k] = KpiRng::stream(seed_, kFalsePositiveKey, k, kPurposeFalsePositives);
  controllers_.assign(class_models_.size() * kNumKpiParams, RunningTargetController(model_.controller));
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
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const double x = u(rng) * static_cast<double>(q.size() - 1);
  const size_t i = std::min(static_cast<size_t>(x), q.size() - 2);
  const double f = x - static_cast<double>(i);
  return q[i] + f * (q[i + 1] - q[i]);
}

namespace {
double wrap_angle(double a) {
  constexpr double pi = std::numbers::pi;
  a = std::fmod(a + pi, 2 * pi);
  if (a < 0) a += 2 * pi;
  return a - pi;
}
}  // namespace

double conditional_feature(const std::string& name, const Object& o, double range, long track_age) {
  const double azimuth = std::atan2(o.position.y(), o.position.x());
  const Eigen::Vector2d v = o.velocity.head<2>();
  const Eigen::Vector2d h(std::cos(o.heading), std::sin(o.heading));
  if (name == "range") return range;
  if (name == "azimuth") return azimuth;
  if (name == "speed") return v.norm();  // BEV, as the loop computes it
  if (name == "radial_velocity")
    return range > 1e-6 ? v.dot(o.position.head<2>() / range) : 0.0;
  if (name == "longitudinal_velocity") return v.dot(h);
  if (name == "lateral_velocity") return -h.y() * v.x() + h.x() * v.y();
  if (name == "acceleration") return o.acceleration.head<2>().norm();  // BEV, as the loop computes it
  if (name == "size") return o.size.x();
  if (name == "box_width") return o.size.y();
  if (name == "box_height") return o.size.z();
  if (name == "heading_to_line_of_sight") {
    const double a = std::abs(wrap_angle(o.heading - azimuth));  // [0, pi]
    return a > std::numbers::pi / 2 ? std::numbers::pi - a : a;
  }
  if (name == "truncation") return o.truncation;
  if (name == "visibility") return o.visible_fraction;
  if (name == "track_age") return static_cast<double>(track_age);
  // Not in kConditionalFeatures (a validated model names none such): a programming error.
  throw Error("kpi manager: conditional feature \"" + name + "\" cannot be computed");
}

namespace {

// The bin of a (present) conditional term for this object.
int term_bin(const ConditionalTerm& ct, const Object& o, double range, long track_age) {
  return ct.bin(conditional_feature(ct.feature, o, range, track_age));
}

}  // namespace

double KpiManager::detection_probability(const ClassModel& cm, int rb, int vb, const Object& o, double range,
                                         long track_age) const {
  double p = cm.detection_probability[rb][vb];
  if (cm.detection_conditional.present())
    p += cm.detection_conditional.bias[term_bin(cm.detection_conditional, o, range, track_age)];
  return std::clamp(p, 0.0, 1.0);
}

double KpiManager::detection_probability(const Object& o, long track_age) const {
  const int slot = class_slot_[static_cast<int>(o.cls)];
  if (slot < 0) return 1;
  const double range = o.position.head<2>().norm();
  return detection_probability(*class_models_[slot], model_.range_bin(range), model_.visibility_bin(o.visible_fraction),
                               o, range, track_age);
}

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
    if (!o.position.allFinite() || !o.velocity.allFinite() || !o.size.allFinite() || !std::isfinite(o.heading))
      throw Error("kpi manager: object " + std::to_string(o.id) + ": position/velocity/size/heading: must be finite");
    if (!std::isfinite(o.visible_fraction))
      throw Error("kpi manager: object " + std::to_string(o.id) + ": visible_fraction: must be finite");
    if (!o.acceleration.allFinite() || !std::isfinite(o.truncation))
      throw Error("kpi manager: object " + std::to_string(o.id) + ": acceleration/truncation: must be finite");
    const ClassModel& cm = *class_models_[slot];
    inj.modelled = true;
    const Eigen::Vector2d bev = o.position.head<2>();
    const double range = bev.norm();
    const int rb = model_.range_bin(range), vb = model_.visibility_bin(o.visible_fraction);
    inj.range_bin = rb;
    inj.visibility_bin = vb;

    TrackState& st = state_for(o.id);
    const bool fresh = st.last_frame < 0;
    const int gap = fresh ? 1 : static_cast<int>(std::min<long>(frame_ - st.last_frame, 1000));
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

    // Errors: advance every parameter's AR(1) state, even when the object will be missed.
    for (int p = 0; p < kNumKpiParams; ++p) {
      const ErrorModel& em = cm.errors[p];
      KpiRng& rng = st.error_rng[p];
      const double eps = sample_innovation(em.innovation, rng);
      if (fresh) {
        st.z[p] = eps;  // stationary start
        st.c[p] = std::normal_distribution<double>(0.0, 1.0)(rng);
      } else {
        st.z[p] = ar1_step(st.z[p], em.ar1, gap, eps);
      }
      const double z = controllers_[slot * kNumKpiParams + p].apply(st.z[p]);
      double bias = 0, scale = 1;
      if (em.conditional.present()) {
        const int b = term_bin(em.conditional, o, range, frame_ - st.first_frame);
        bias = em.conditional.bias[b];
        if (!em.conditional.scale.empty()) scale = em.conditional.scale[b];
      }
      inj.error[p] = options_.noise ? em.mean[rb] + bias + em.sigma[rb] * scale * em.visibility_std_scale[vb] * z +
                                          em.track_std * st.c[p]
                                    : 0.0;
    }
    const double pd = detection_probability(cm, rb, vb, o, range, frame_ - st.first_frame);
    inj.detection_probability = pd;
    const bool missed = st.miss.step(1 - pd, cm.miss_burst_mean, st.miss_rng);
    const bool flipped = st.flip.step(cm.heading_flip_probability, cm.flip_burst_mean, st.flip_rng);
    inj.detected = !(options_.misses && missed);
    inj.flipped = options_.flips && flipped;
    if (!inj.detected) continue;

    Object r = o;
    const Eigen::Vector2d u = range > 1e-6 ? Eigen::Vector2d(bev / range) : Eigen::Vector2d(1, 0);
    const Eigen::Vector2d left(-u.y(), u.x());
    const auto& e = inj.error;
    r.position.head<2>() += e[int(KpiParam::PositionAlong)] * u + e[int(KpiParam::PositionAcross)] * left;
    r.position.z() += e[int(KpiParam::PositionVertical)];
    r.velocity.head<2>() += e[int(KpiParam::VelocityAlong)] * u + e[int(KpiParam::VelocityAcross)] * left;
    r.size.x() = std::max(0.05, r.size.x() + e[int(KpiParam::Length)]);
    r.size.y() = std::max(0.05, r.size.y() + e[int(KpiParam::Width)]);
    r.size.z() = std::max(0.05, r.size.z() + e[int(KpiParam::Height)]);
    r.heading = wrap_angle(r.heading + e[int(KpiParam::Heading)] + (inj.flipped ? std::numbers::pi : 0.0));
    r.score = sample_quantiles(cm.score_quantiles, 1.0, st.score_rng);
    reported.push_back(r);
  }

  if (options_.false_positives) {
    for (int k = 0; k < 8; ++k) {
      const int slot = class_slot_[k];
      if (slot < 0) continue;
      const ClassModel& cm = *class_models_[slot];
      // Each model once, under its own class (not again for the classes that fall back to it).
      if (model_.classes.count(kpi_class_name(static_cast<ObjectClass>(k))) == 0) continue;
      const FalsePositiveTable& table = cm.fp_table;
      if (table.present() ? table.total_rate() <= 0 : cm.false_positive_rate <= 0) continue;
      KpiRng& rng = fp_rng_[k];
      // n false positives placed by the given quantiles (empty: the class's), from the class's stream.
      auto emit = [&](double rate, const std::vector<double>& rq, const std::vector<double>& aq,
                      const std::vector<double>& sq) {
        std::poisson_distribution<int> poisson(rate);
        const int n = poisson(rng);
        for (int f = 0; f < n; ++f) {
          Object fp;
          fp.id = next_fp_id_--;
          if (next_fp_id_ < -1000000000) next_fp_id_ = -1000;
          fp.cls = static_cast<ObjectClass>(k);
          const double rr = sample_quantiles(rq.empty() ? cm.fp_range_quantiles : rq, 20, rng),
                       az = sample_quantiles(aq.empty() ? cm.fp_azimuth_quantiles : aq, 0, rng);
          fp.position = Eigen::Vector3d(rr * std::cos(az), rr * std::sin(az), cm.fp_z);
          fp.size = cm.mean_size;
          std::uniform_real_distribution<double> h(-std::numbers::pi, std::numbers::pi);
          fp.heading = h(rng);
          fp.visible_fraction = 1;
          fp.score = sample_quantiles(sq.empty() ? cm.fp_score_quantiles : sq, 0.5, rng);
          reported.push_back(fp);
        }
      };
      if (!table.present()) {
        emit(cm.false_positive_rate, {}, {}, {});
        continue;
      }
      // A table: each bin its own Poisson count, placed by the bin's quantiles.
      static const std::vector<double> none;
      auto at = [](const std::vector<std::vector<double>>& q, size_t b) -> const std::vector<double>& {
        return q.empty() ? none : q[b];
      };
      for (size_t b = 0; b < table.rate.size(); ++b)
        if (table.rate[b] > 0)
          emit(table.rate[b], at(table.range_quantiles, b), at(table.azimuth_quantiles, b), at(table.score_quantiles, b));
    }
  }
  if (frame_ % 64 == 0) forget_stale();
}

}  // namespace lidarsim::sensor
