// The KPI model's optional false-positive table (ClassModel::fp_table): per bin its own
// Poisson rate and placement quantiles, drawn by the KPI manager from the class's own stream; absent,
// the file and every draw are those of a model without the table.
#include <gtest/gtest.h>

#include <cmath>
#include <nlohmann/json.hpp>

#include "common/error.h"
#include "sensor/kpi_manager.h"
#include "sensor/kpi_model.h"

namespace lidarsim::sensor {
namespace {

// Two azimuth bins: right of the sensor 0.5 per frame at 10-20 m, left 2.0 per frame at 40-50 m.
FalsePositiveTable two_bins() {
  FalsePositiveTable t;
  t.feature = "azimuth";
  t.edges = {-3.2, 0.0};
  t.rate = {0.5, 2.0};
  t.range_quantiles = {{10, 15, 20}, {40, 45, 50}};
  t.azimuth_quantiles = {{-0.6, -0.3, -0.1}, {0.1, 0.3, 0.6}};
  return t;
}

Object fp_car(int id, double x, double y) {
  Object o;
  o.id = id;
  o.position = {x, y, -0.9};
  o.size = {4, 1.8, 1.5};
  return o;
}

TEST(KpiFpTable, EachBinDrawsItsOwnPoissonCountAndPlacementOver4000Frames) {
  KpiModel m = default_kpi_model();
  m.classes["Car"].fp_table = two_bins();
  KpiOptions opt;
  opt.misses = false;
  KpiManager kpi(m, 3, opt);
  std::vector<Object> truth{fp_car(1, 20, 0)}, out;
  const int frames = 4000;
  double n[2] = {0, 0};
  for (int f = 0; f < frames; ++f) {
    kpi.apply(truth, out);
    for (const Object& o : out) {
      if (o.id > -1000 || o.cls != ObjectClass::Car) continue;
      const double az = std::atan2(o.position.y(), o.position.x()), r = o.position.head<2>().norm();
      const int b = az < 0 ? 0 : 1;
      ++n[b];
      if (b == 0) {
        EXPECT_GE(r, 10 - 1e-9);
        EXPECT_LE(r, 20 + 1e-9);
      } else {
        EXPECT_GE(r, 40 - 1e-9);
        EXPECT_LE(r, 50 + 1e-9);
      }
    }
  }
  // Poisson: sd of the mean rate sqrt(rate / frames) ~ 0.011 and 0.022.
  EXPECT_NEAR(n[0] / frames, 0.5, 0.05);
  EXPECT_NEAR(n[1] / frames, 2.0, 0.1);
}

// Common random numbers: a table on Pedestrian leaves every Car false positive, every track draw,
// miss and score exactly as they were; only the Pedestrian false positives change.
TEST(KpiFpTable, ATableOnOneClassLeavesEveryOtherDrawUnchanged) {
  const KpiModel plain = default_kpi_model();
  KpiModel changed = plain;
  changed.classes["Pedestrian"].fp_table = two_bins();
  KpiManager a(plain, 5), b(changed, 5);
  std::vector<Object> truth, oa, ob;
  for (int i = 0; i < 5; ++i) {
    truth.push_back(fp_car(i, 8.0 + 9 * i, 3.0 - i));
    if (i % 2) truth.back().cls = ObjectClass::Pedestrian;
  }
  int ped_differs = 0;
  for (int f = 0; f < 300; ++f) {
    a.apply(truth, oa);
    b.apply(truth, ob);
    for (size_t i = 0; i < truth.size(); ++i) {
      ASSERT_EQ(a.injections()[i].detected, b.injections()[i].detected) << "frame " << f;
      for (int p = 0; p < kNumKpiParams; ++p) ASSERT_EQ(a.injections()[i].error[p], b.injections()[i].error[p]);
    }
    std::vector<Object> ca, cb, pa, pb;
    for (const Object& o : oa) (o.id > -1000 ? ca : o.cls == ObjectClass::Pedestrian ? pa : ca).push_back(o);
    for (const Object& o : ob) (o.id > -1000 ? cb : o.cls == ObjectClass::Pedestrian ? pb : cb).push_back(o);
    ASSERT_EQ(ca.size(), cb.size()) << "frame " << f;
    for (size_t k = 0; k < ca.size(); ++k) {
      ASSERT_EQ(ca[k].position, cb[k].position) << "frame " << f;
      ASSERT_EQ(ca[k].score, cb[k].score) << "frame " << f;
    }
    ped_differs += pa.size() != pb.size() || (!pa.empty() && pa[0].position != pb[0].position);
  }
  EXPECT_GT(ped_differs, 0) << "the changed class's false positives do change";
}

TEST(KpiFpTable, AbsentTableIsNotWrittenAndATableRoundTrips) {
  const KpiModel plain = default_kpi_model();
  EXPECT_EQ(kpi_model_to_json(plain).find("fp_table"), std::string::npos);
  KpiModel m = plain;
  m.classes["Car"].fp_table = two_bins();
  m.classes["Car"].fp_table.score_quantiles = {{}, {0, 1, 2}};  // bin 0: the class's score quantiles
  const std::string text = kpi_model_to_json(m);
  const KpiModel back = parse_kpi_model(text, "m.json");
  EXPECT_EQ(kpi_model_to_json(back), text);
  EXPECT_EQ(back.classes.at("Car").fp_table.rate, (std::vector<double>{0.5, 2.0}));
  EXPECT_EQ(back.classes.at("Car").fp_table.bin(-0.5), 0);
  EXPECT_EQ(back.classes.at("Car").fp_table.bin(0.5), 1);
  EXPECT_EQ(back.classes.at("Car").fp_table.bin(-9), 0);
}

std::string fp_table_parse_error(const nlohmann::json& j) {
  try {
    parse_kpi_model(j.dump(), "m.json");
  } catch (const Error& e) {
    return e.what();
  }
  return "(no error)";
}

TEST(KpiFpTable, BadTablesAreOneErrorNamingFileAndField) {
  KpiModel m = default_kpi_model();
  m.classes["Car"].fp_table = two_bins();
  const auto good = nlohmann::json::parse(kpi_model_to_json(m));
  const std::string f = "m.json: classes.Car.fp_table";
  auto with = [&](const char* key, nlohmann::json v) {
    auto j = good;
    j["classes"]["Car"]["fp_table"][key] = v;
    return fp_table_parse_error(j);
  };
  EXPECT_EQ(fp_table_parse_error(good), "(no error)");
  EXPECT_NE(with("feature", "speed").find(f + ".feature: must be range, azimuth or score"), std::string::npos);
  EXPECT_NE(with("rate", {0.5}).find(f + ".rate: must have 2 entries, got 1"), std::string::npos);
  EXPECT_NE(with("rate", {0.5, -1}).find(f + ".rate[1]: must be in"), std::string::npos);
  EXPECT_NE(with("edges", {0, 0}).find(f + ".edges[1]: must increase"), std::string::npos);
  EXPECT_NE(with("range_quantiles", {{1, 2}}).find(f + ".range_quantiles: must have 2 entries"), std::string::npos);
  EXPECT_NE(with("azimuth_quantiles", {{1, 2}, {3, 1}}).find(f + ".azimuth_quantiles[1][1]: must not decrease"),
            std::string::npos);
  // A bin with a rate and no quantiles of its own needs the class's.
  auto j = good;
  j["classes"]["Car"]["fp_table"]["range_quantiles"] = {nlohmann::json::array(), {40, 50}};
  j["classes"]["Car"]["fp_range_quantiles"] = nlohmann::json::array();
  j["classes"]["Car"]["false_positive_rate"] = 0;
  EXPECT_NE(fp_table_parse_error(j).find(f + ".range_quantiles[0]: needed"), std::string::npos) << fp_table_parse_error(j);
}

}  // namespace
}  // namespace lidarsim::sensor
