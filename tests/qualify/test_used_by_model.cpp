// Which object loop candidates the base KPI model already holds (qualify/objects/object_candidates.h
// used_by_model): judged per feature, target and form, not per feature. Occlusion (the model's
// visibility bin) conditions detection and the errors' spread but no error's mean, so an error's
// mean form of occlusion is a candidate like any other.
#include <gtest/gtest.h>

#include <string>

#include "qualify/objects/object_candidates.h"
#include "qualify/objects/object_folds.h"
#include "sensor/kpi_model.h"

using namespace lidarsim;
using namespace lidarsim::qualify;
using qualify::obj::Kind;
using qualify::obj::used_by_model;

namespace {

int target_index(const std::string& name) {
  for (int t = 0; t < kObjectTargetCount; ++t)
    if (kObjectTargets[t] == name) return t;
  ADD_FAILURE() << "no target " << name;
  return 0;
}

}  // namespace

TEST(ObjectLoopUsedByModel, OcclusionIsUsedInDetectionAndInAnErrorsSpreadButNotInItsMean) {
  const int length = target_index("length"), detection = target_index("detection");
  EXPECT_TRUE(used_by_model("occlusion", detection, Kind::RateTable));
  EXPECT_TRUE(used_by_model("occlusion", detection, Kind::RateWindow));
  for (int t = 0; t < kObjectTargetCount; ++t) {
    if (t == detection) continue;
    EXPECT_FALSE(used_by_model("occlusion", t, Kind::MeanTable)) << kObjectTargets[t];
    EXPECT_FALSE(used_by_model("occlusion", t, Kind::MeanWindow)) << kObjectTargets[t];
    EXPECT_TRUE(used_by_model("occlusion", t, Kind::SpreadTable)) << kObjectTargets[t];
    EXPECT_TRUE(used_by_model("occlusion", t, Kind::SpreadWindow)) << kObjectTargets[t];
  }
  // A Candidate is judged by its own feature, target and form.
  obj::Candidate c;
  c.feature = obj::feature_index("occlusion"), c.target = length, c.kind = Kind::MeanWindow;
  EXPECT_FALSE(used_by_model(c));
  c.kind = Kind::SpreadTable;
  EXPECT_TRUE(used_by_model(c));
}

// Range is held by the model only in its fixed bins, and every candidate is fitted net of them: a
// detection edge or a spread growing within a bin is what a range candidate scores, so none of its
// forms is "used by the model" (a dropout beyond 35 m scored 0.15 held out and was never ranked).
TEST(ObjectLoopUsedByModel, ClassIsUsedEverywhereRangeAndOtherFeaturesNowhere) {
  for (int t = 0; t < kObjectTargetCount; ++t)
    for (Kind k : obj::kinds_for(t))
      for (const std::string& f : kObjectFeatures) {
        const bool expected = f == "class" || (f == "occlusion" && (t == kDetectionTarget || obj::is_spread(k)));
        EXPECT_EQ(used_by_model(f, t, k), expected) << f << " on " << kObjectTargets[t] << " " << obj::to_string(k);
      }
}

// The predicate agrees with what the base model's residual depends on (object_folds.h
// base_residual): an error's residual is the same in every visibility bin, detection's is not.
TEST(ObjectLoopUsedByModel, AgreesWithWhatTheBaseModelsResidualDependsOn) {
  const sensor::KpiModel m = sensor::default_kpi_model();
  ASSERT_GE(m.visibility_bins(), 2);
  ObjectRecord r;
  r.cls = 0, r.range_bin = 1, r.detected = true;
  r.value = {0.3, -0.2, 0.5, 0.1, 0.05, 0.02, 1.0};
  r.feature.assign(kObjectFeatures.size(), 0.0);
  for (int t = 0; t < kObjectTargetCount; ++t) {
    bool depends = false;
    for (int v = 1; v < m.visibility_bins(); ++v) {
      ObjectRecord a = r, b = r;
      a.visibility_bin = 0, b.visibility_bin = v;
      depends |= obj::base_residual(m, a, t) != obj::base_residual(m, b, t);
    }
    const Kind bias = t == kDetectionTarget ? Kind::RateTable : Kind::MeanTable;
    EXPECT_EQ(used_by_model("occlusion", t, bias), depends) << kObjectTargets[t];
  }
  // The errors' spread is scaled per visibility bin.
  const auto& scale = m.classes.at("Car").errors[int(sensor::KpiParam::Length)].visibility_std_scale;
  EXPECT_NE(scale.front(), scale.back());
}
