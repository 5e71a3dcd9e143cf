// The noise of an error once the loop's term takes its part (qualify/objects/object_terms.h
// shrink_noise_for_term): a term that carried the error's heavy tails and its correlation along a
// track (a lag on the few fast objects) leaves the noise's own shape, not the base's. And the
// error model fitted from samples alone (sensor/kpi_fit.h fit_error_model).
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "qualify/objects/object_folds.h"
#include "qualify/objects/object_terms.h"
#include "sensor/kpi_fit.h"

namespace {

namespace obj = lidarsim::qualify::obj;
namespace sensor = lidarsim::sensor;
using Innovation = sensor::Innovation;

// 60 tracks of 40 frames, class Car, one range and visibility bin; a fifth of them "fast"
// (feature +-10, constant along the track), the rest at 0; error = -0.2 x feature + iid N(0, 0.1).
struct LagData {
  std::vector<lidarsim::qualify::ObjectRecord> recs;
  LagData() {
    std::mt19937_64 rng(11);
    std::normal_distribution<double> noise(0.0, 0.1);
    const int f = obj::feature_index("radial_velocity");
    for (int track = 0; track < 60; ++track) {
      const double x = track % 5 == 0 ? (track % 10 == 0 ? 10.0 : -10.0) : 0.0;
      for (int frame = 0; frame < 40; ++frame) {
        lidarsim::qualify::ObjectRecord r;
        r.seq = 0, r.track = track, r.frame = frame, r.cls = 0, r.detected = true;
        r.feature.assign(lidarsim::qualify::kObjectFeatures.size(), 0.0);
        r.feature[f] = x;
        r.value.fill(std::nan(""));
        r.value[0] = -0.2 * x + noise(rng);
        recs.push_back(r);
      }
    }
  }
  obj::Split split() const {
    obj::Split s;
    for (const auto& r : recs) s.r.push_back(r.value[0]), s.rec.push_back(&r);
    return s;
  }
};

std::vector<sensor::ErrorSample> samples_of(const LagData& d, bool with_lag) {
  std::vector<sensor::ErrorSample> out;
  const int f = obj::feature_index("radial_velocity");
  for (const auto& r : d.recs)
    out.push_back({r.seq, r.track, r.frame, 0, 0, r.value[0] + (with_lag ? 0.0 : 0.2 * r.feature[f])});
  return out;
}

sensor::FitOptions one_bin() {
  sensor::FitOptions o;
  o.range_bin_edges = {0}, o.visibility_bin_edges = {0};
  return o;
}

TEST(KpiFitErrorModel, FitsTheNoisesOwnShapeFromSamples) {
  const LagData d;
  const sensor::ErrorModel lag = sensor::fit_error_model(samples_of(d, true), one_bin(), false);
  const sensor::ErrorModel own = sensor::fit_error_model(samples_of(d, false), one_bin(), false);
  // With the lag in it the error is wide and correlated along tracks; without, iid Gaussian.
  EXPECT_GT(lag.ar1, 0.8);
  EXPECT_GT(lag.sigma[0], 0.5);
  EXPECT_EQ(own.innovation.type, Innovation::Type::Gaussian);
  EXPECT_LT(std::abs(own.ar1), 0.1);
  EXPECT_NEAR(own.sigma[0], 0.1, 0.01);
  auto bad = samples_of(d, false);
  bad[7].range_bin = 3;
  EXPECT_THROW(sensor::fit_error_model(bad, one_bin(), false), std::exception) << "a bin outside the options";
}

// Before, the shrink scaled sigma only and kept the base's AR(1) and mixture, which were the
// lag's: the simulated errors with the term came out correlated along tracks where the data's
// noise is not.
TEST(TermNoise, ATermThatCarriedTheTailsLeavesGaussianUncorrelatedNoise) {
  const LagData d;
  const obj::Split s = d.split();
  sensor::KpiModel m;
  m.range_bin_edges = {0}, m.visibility_bin_edges = {0};
  sensor::ClassModel car;
  sensor::ErrorModel& em = car.errors[int(sensor::KpiParam::PositionAlong)];
  em = sensor::fit_error_model(samples_of(d, true), one_bin(), false);  // what calibration fits
  ASSERT_GT(em.ar1, 0.8);
  m.classes["Car"] = car;
  const obj::Refit term = obj::backfit(s.column(obj::feature_index("radial_velocity")), s.r, s.classes(),
                                       s.cells(0, 1), 3);
  ASSERT_NEAR(term(0, 0, 10.0), -2.0, 0.1);
  obj::shrink_noise_for_term(m, term, 0, "radial_velocity", s, lidarsim::qualify::winsor_limits(s.r), 1);
  const sensor::ErrorModel& after = m.classes["Car"].errors[int(sensor::KpiParam::PositionAlong)];
  EXPECT_EQ(after.innovation.type, Innovation::Type::Gaussian);
  EXPECT_LT(std::abs(after.ar1), 0.1);
  EXPECT_LT(after.sigma[0], em.sigma[0] * 0.25) << "the sigma shrunk by the variance the term explains";
}

}  // namespace
