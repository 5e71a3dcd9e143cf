// The false-positive analysis integrates a model's quantiles into expected counts per grid cell
// (qualify/objects/object_false_positives.h); those must be what the KPI manager draws, or the loop would
// judge a model it does not simulate. Checked cell by cell against 20000 simulated frames, for the
// class quantiles and for a table written by with_fp_table.
#include <gtest/gtest.h>

#include <cmath>

#include "qualify/objects/object_false_positives.h"
#include "sensor/kpi_manager.h"

using namespace lidarsim;
using namespace lidarsim::qualify::obj;

namespace {

// Simulated false positives per frame and cell of Car, against the compiled expected counts.
void expect_cells_match(const sensor::KpiModel& model, const FpModel& fp, const FpGrid& g) {
  sensor::KpiOptions opt;
  sensor::KpiManager kpi(model, 7, opt);
  std::vector<sensor::Object> truth, out;
  const int frames = 20000;
  std::vector<double> n(g.cells(), 0.0);
  for (int f = 0; f < frames; ++f) {
    kpi.apply(truth, out);
    for (const auto& o : out)
      if (o.id <= -1000 && o.cls == sensor::ObjectClass::Car)
        n[g.cell(o.position.head<2>().norm(), std::atan2(o.position.y(), o.position.x()), o.score)] += 1;
  }
  double total = 0;
  for (int k = 0; k < g.cells(); ++k) {
    const double mu = fp.mu[0][0][k];
    total += mu;
    // 4 Poisson standard deviations of the cell's mean over the frames, plus the floor.
    EXPECT_NEAR(n[k] / frames, mu, 4 * std::sqrt(std::max(mu, 1e-4) / frames) + 1e-4) << "cell " << k;
  }
  EXPECT_GT(total, 0.1);
}

FpGrid grid() {
  FpGrid g;
  g.range = {10, 20, 35};
  g.azimuth = {-0.3, 0.1, 0.4};
  g.score = {1, 3};
  return g;
}

}  // namespace

TEST(FpModel, ExpectedCountsPerCellAreWhatTheKpiManagerDrawsFromTheClassQuantiles) {
  sensor::KpiModel m = sensor::default_kpi_model();
  auto& car = m.classes.at("Car");
  car.false_positive_rate = 1.5;
  car.fp_range_quantiles = {5, 12, 18, 30, 60};
  car.fp_azimuth_quantiles = {-0.7, -0.2, 0.0, 0.5, 0.7};
  car.fp_score_quantiles = {0, 0.5, 2, 5};
  const FpGrid g = grid();
  FpModel fp = fp_base(m);
  fp.compile(g, {0, 0, 0});
  expect_cells_match(m, fp, g);
}

TEST(FpModel, ExpectedCountsPerCellAreWhatTheKpiManagerDrawsFromAWrittenTable) {
  sensor::KpiModel m = sensor::default_kpi_model();
  FpModel fp;
  fp.feature = 1;  // azimuth
  fp.cuts = {-0.6, -0.26};
  fp.comps[0] = {{0.4, {5, 30, 60}, {-0.8, -0.7, -0.6}, {0, 1, 4}},
                 {0.9, {15, 20, 25}, {-0.6, -0.4, -0.26}, {2, 3, 4}},
                 {1.2, {5, 40, 60}, {-0.26, 0.3, 0.8}, {0, 0.5, 1}}};
  const sensor::KpiModel with = with_fp_table(m, fp);
  ASSERT_TRUE(with.classes.at("Car").fp_table.present());
  with.validate();
  const FpGrid g = grid();
  fp.compile(g, {0, 0, 0});
  expect_cells_match(with, fp, g);
}
