// The KPI model's optional false-positive persistence (ClassModel::fp_persistence): a false
// positive survives to the next frame with a probability (ghost tracks, as PointRCNN's on KITTI), keeps
// its id and class, moves by a jitter, its score follows a copula AR(1); births at rate x (1 - survival)
// keep the mean count. Absent, every draw is that of a model without persistence.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <map>
#include <nlohmann/json.hpp>

#include "common/error.h"
#include "sensor/kpi_manager.h"
#include "sensor/kpi_model.h"

namespace lidarsim::sensor {
namespace {

Object truth_object(int id, ObjectClass cls, double x, double y) {
  Object o;
  o.id = id;
  o.cls = cls;
  o.position = {x, y, -0.9};
  o.size = {4, 1.8, 1.5};
  o.visible_fraction = 0.9;
  return o;
}

// FNV-1a over the bit patterns of everything the manager reports, frame by frame.
struct Digest {
  std::uint64_t h = 1469598103934665603ull;
  void add(const void* p, size_t n) {
    const auto* b = static_cast<const unsigned char*>(p);
    for (size_t i = 0; i < n; ++i) h = (h ^ b[i]) * 1099511628211ull;
  }
  void add(double v) { add(&v, sizeof v); }
  void add(const Object& o) {
    add(&o.id, sizeof o.id);
    const int c = static_cast<int>(o.cls);
    add(&c, sizeof c);
    for (int k = 0; k < 3; ++k) add(o.position[k]), add(o.size[k]), add(o.velocity[k]);
    add(o.heading), add(o.score);
  }
};

std::uint64_t digest_of(const KpiModel& m, std::uint64_t seed, int frames) {
  KpiManager kpi(m, seed);
  std::vector<Object> truth, out;
  for (int i = 0; i < 6; ++i)
    truth.push_back(truth_object(i + 1, i % 3 == 0 ? ObjectClass::Car : i % 3 == 1 ? ObjectClass::Pedestrian
                                                                                    : ObjectClass::Cyclist,
                                 6.0 + 7 * i, 4.0 - 1.5 * i));
  Digest d;
  for (int f = 0; f < frames; ++f) {
    for (Object& o : truth) o.position.x() += 0.1;
    kpi.apply(truth, out);
    const size_t n = out.size();
    d.add(&n, sizeof n);
    for (const Object& o : out) d.add(o);
  }
  return d.h;
}

// The digest of 300 frames of the default model (seed 7, no persistence field), a golden value
// taken from the KPI manager without persistence (commit 2dbf72f): without the field the draws must
// stay these bits.
TEST(KpiFpPersistence, WithoutTheFieldEveryDrawIsAsBefore) {
  EXPECT_EQ(digest_of(default_kpi_model(), 7, 300), 0x443333e3f269ed28ull);
  KpiModel table = default_kpi_model();
  FalsePositiveTable t;
  t.feature = "azimuth";
  t.edges = {-3.2, 0.0};
  t.rate = {0.5, 2.0};
  t.range_quantiles = {{10, 15, 20}, {40, 45, 50}};
  table.classes["Car"].fp_table = t;
  EXPECT_EQ(digest_of(table, 7, 300), 0x68bf4b9429774459ull);
}

// Only Car false positives (rate 1.5 per frame), nothing else drawn.
KpiModel car_clutter(double survival, double jitter, double score_ar1) {
  KpiModel m = default_kpi_model();
  for (auto& [name, c] : m.classes) c.false_positive_rate = 0;
  ClassModel& car = m.classes.at("Car");
  car.false_positive_rate = 1.5;
  car.fp_persistence = {survival, 1, jitter, score_ar1};
  return m;
}

// The same id a frame later is a ghost track: its share, lifetimes, mean count, jitter and score follow
// the field; the mean count is the class's rate whatever the survival.
TEST(KpiFpPersistence, GhostsKeepTheirIdSurviveGeometricallyAndKeepTheMeanCount) {
  const double s = 0.8, jitter = 0.05;
  KpiManager kpi(car_clutter(s, jitter, 0.9), 11);
  std::vector<Object> none, out;
  std::map<int, Object> prev;
  std::map<int, int> life;  // id -> frames seen
  double n = 0, n2 = 0, seen_again = 0, step2 = 0, steps = 0, dscore = 0, score_sum = 0;
  const int frames = 4000;
  for (int f = 0; f < frames; ++f) {
    kpi.apply(none, out);
    std::map<int, Object> cur;
    for (const Object& o : out) {
      ASSERT_LE(o.id, -1000);
      ASSERT_EQ(o.cls, ObjectClass::Car);
      cur[o.id] = o;
      ++life[o.id];
      score_sum += o.score;
      const auto it = prev.find(o.id);
      if (it == prev.end()) continue;
      ++seen_again;
      step2 += (o.position - it->second.position).head<2>().squaredNorm();
      dscore += std::abs(o.score - it->second.score);
      ++steps;
    }
    n += out.size(), n2 += double(out.size()) * out.size();
    prev = std::move(cur);
  }
  const double mean = n / frames;
  EXPECT_NEAR(mean, 1.5, 0.15);                               // births 0.3 per frame, life 5 frames
  EXPECT_NEAR(n2 / frames - mean * mean, 1.5, 0.3);           // stationary: Poisson counts
  EXPECT_NEAR(seen_again / n, s, 0.03);                       // share with the same id a frame before
  EXPECT_NEAR(std::sqrt(step2 / steps / 2), jitter, 0.005);   // per-axis step
  double lives = 0;
  for (const auto& [id, l] : life) lives += l;
  EXPECT_NEAR(lives / life.size(), 1 / (1 - s), 0.3);         // geometric lifetime, mean 5 frames
  // The default model's Car false-positive scores span 0-5: consecutive scores of a ghost differ
  // little with score_ar1 0.9 (a fresh draw: about 1.7 on average).
  EXPECT_LT(dscore / steps, 0.8);
  // ... while the scores keep the quantiles' distribution: uniform on [0, 1] and [1, 5], mean 1.75.
  EXPECT_NEAR(score_sum / n, 1.75, 0.12);
}

// A share of ghosts: the rest last one frame; the mean count is still the rate, the share with the
// same id a frame before is ghost_share x survival, and a ghost's run continues with the survival.
TEST(KpiFpPersistence, AShareOfGhostsTheRestOneFrame) {
  KpiModel m = car_clutter(0.8, 0, 1);
  m.classes.at("Car").fp_persistence.ghost_share = 0.4;
  KpiManager kpi(m, 13);
  std::vector<Object> none, out;
  std::map<int, int> life;
  double n = 0, again = 0;
  std::map<int, Object> prev;
  const int frames = 6000;
  for (int f = 0; f < frames; ++f) {
    kpi.apply(none, out);
    std::map<int, Object> cur;
    for (const Object& o : out) {
      cur[o.id] = o;
      ++life[o.id];
      again += prev.count(o.id);
    }
    n += out.size();
    prev = std::move(cur);
  }
  EXPECT_NEAR(n / frames, 1.5, 0.12);
  EXPECT_NEAR(again / n, 0.4 * 0.8, 0.03);
  double longer = 0, at_least_2 = 0, at_least_3 = 0;
  for (const auto& [id, l] : life) longer += l > 1, at_least_2 += std::max(0, l - 1), at_least_3 += std::max(0, l - 2);
  EXPECT_NEAR(at_least_3 / at_least_2, 0.8, 0.03);  // continuation of a ghost's run
  EXPECT_GT(longer, 100);
}

// Ego motion: a ghost stays put in the world, so in the sensor frame it moves back by the step.
TEST(KpiFpPersistence, WithEgoMotionGhostsStayPutInTheWorld) {
  KpiManager kpi(car_clutter(0.95, 0, 1), 3);
  std::vector<Object> none, out;
  std::map<int, Eigen::Vector3d> prev;
  int checked = 0;
  for (int f = 0; f < 200; ++f) {
    kpi.set_ego_motion(Eigen::Vector2d(1.0, 0.0), 0.0);
    kpi.apply(none, out);
    for (const Object& o : out) {
      const auto it = prev.find(o.id);
      if (it == prev.end()) continue;
      EXPECT_NEAR(o.position.x(), it->second.x() - 1.0, 1e-9);
      EXPECT_NEAR(o.position.y(), it->second.y(), 1e-9);
      ++checked;
    }
    prev.clear();
    for (const Object& o : out) prev[o.id] = o.position;
  }
  EXPECT_GT(checked, 100);
}

// Common random numbers: persistence on Car leaves every Pedestrian and Cyclist false positive and
// every track draw as it was; the Car false positives change.
TEST(KpiFpPersistence, PersistenceOnOneClassLeavesEveryOtherDrawUnchanged) {
  const KpiModel plain = default_kpi_model();
  KpiModel changed = plain;
  changed.classes["Car"].fp_persistence = {0.7, 0.6, 0.1, 0.5};
  KpiManager a(plain, 5), b(changed, 5);
  std::vector<Object> truth{truth_object(1, ObjectClass::Car, 10, 1), truth_object(2, ObjectClass::Pedestrian, 15, -2)},
      oa, ob;
  int car_differs = 0;
  for (int f = 0; f < 300; ++f) {
    a.apply(truth, oa);
    b.apply(truth, ob);
    std::vector<Object> ra, rb, ca, cb;
    for (const Object& o : oa) (o.id <= -1000 && o.cls == ObjectClass::Car ? ca : ra).push_back(o);
    for (const Object& o : ob) (o.id <= -1000 && o.cls == ObjectClass::Car ? cb : rb).push_back(o);
    ASSERT_EQ(ra.size(), rb.size()) << "frame " << f;
    for (size_t k = 0; k < ra.size(); ++k) {
      ASSERT_EQ(ra[k].position, rb[k].position) << "frame " << f;
      ASSERT_EQ(ra[k].score, rb[k].score) << "frame " << f;
      if (ra[k].id > -1000) {
        ASSERT_EQ(ra[k].id, rb[k].id);
      }
    }
    car_differs += ca.size() != cb.size() || (!ca.empty() && ca[0].position != cb[0].position);
  }
  EXPECT_GT(car_differs, 0);
}

TEST(KpiFpPersistence, AbsentFieldIsNotWrittenAndTheFieldRoundTrips) {
  const KpiModel plain = default_kpi_model();
  EXPECT_EQ(kpi_model_to_json(plain).find("fp_persistence"), std::string::npos);
  KpiModel m = plain;
  m.classes["Cyclist"].fp_persistence = {0.42, 0.7, 0.13, 0.6};
  const std::string text = kpi_model_to_json(m);
  const KpiModel back = parse_kpi_model(text, "m.json");
  EXPECT_EQ(kpi_model_to_json(back), text);
  EXPECT_EQ(back.classes.at("Cyclist").fp_persistence.survival, 0.42);
  EXPECT_EQ(back.classes.at("Cyclist").fp_persistence.ghost_share, 0.7);
  EXPECT_EQ(back.classes.at("Cyclist").fp_persistence.jitter, 0.13);
  EXPECT_EQ(back.classes.at("Cyclist").fp_persistence.score_ar1, 0.6);
  EXPECT_FALSE(back.classes.at("Car").fp_persistence.present());
}

std::string persistence_parse_error(const nlohmann::json& j) {
  try {
    parse_kpi_model(j.dump(), "m.json");
  } catch (const Error& e) {
    return e.what();
  }
  return "(no error)";
}

TEST(KpiFpPersistence, BadFieldsAreOneErrorNamingFileAndField) {
  KpiModel m = default_kpi_model();
  m.classes["Car"].fp_persistence = {0.5, 0.8, 0.1, 0.5};
  const auto good = nlohmann::json::parse(kpi_model_to_json(m));
  const std::string f = "m.json: classes.Car.fp_persistence";
  auto with = [&](const char* key, nlohmann::json v) {
    auto j = good;
    j["classes"]["Car"]["fp_persistence"][key] = v;
    return persistence_parse_error(j);
  };
  EXPECT_EQ(persistence_parse_error(good), "(no error)");
  EXPECT_NE(with("survival", 1.0).find(f + ".survival: must be in [0, 0.999]"), std::string::npos) << with("survival", 1.0);
  EXPECT_NE(with("survival", -0.1).find(f + ".survival: must be in"), std::string::npos);
  EXPECT_NE(with("survival", "high").find(f + ".survival"), std::string::npos);
  EXPECT_NE(with("ghost_share", 0).find(f + ".ghost_share: must be in (0, 1]"), std::string::npos);
  EXPECT_NE(with("jitter", -1).find(f + ".jitter: must be in [0, 100] m"), std::string::npos);
  EXPECT_NE(with("score_ar1", 1.5).find(f + ".score_ar1: must be in [0, 1]"), std::string::npos);
  auto j = good;
  j["classes"]["Car"]["fp_persistence"].erase("survival");
  EXPECT_NE(persistence_parse_error(j).find(f + ".survival"), std::string::npos) << persistence_parse_error(j);
  j = good;
  j["classes"]["Car"]["fp_persistence"] = 0.5;
  EXPECT_NE(persistence_parse_error(j).find(f + ": must be an object"), std::string::npos) << persistence_parse_error(j);
}

}  // namespace
}  // namespace lidarsim::sensor
