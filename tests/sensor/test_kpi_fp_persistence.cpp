// The KPI model's optional false-positive persistence (ClassModel::fp_persistence, issue 11): a false
// positive survives to the next frame with a probability (ghost tracks, as PointRCNN's on KITTI), keeps
// its id and class, moves by a jitter, its score follows a copula AR(1); births at rate x (1 - survival)
// keep the mean count. Absent, every draw is as before the field existed.
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

// The digest of 300 frames of the default model (seed 7), taken with the KPI manager as it was before
// the persistence field existed (commit 2dbf72f): without the field the draws must stay bit for bit.
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

}  // namespace
}  // namespace lidarsim::sensor
