// KPI manager: statistics of the injected errors, bursty misses, flips, false positives, the
// feedback controller, the line-of-sight decomposition, and the model file's error messages.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <numeric>

#include "common/error.h"
#include "sensor/kpi_manager.h"
#include "sensor/kpi_model.h"
#include "sensor/kpi_noise.h"
#include "tests/support/temp_path.h"

namespace lidarsim::sensor {
namespace {

// One class, one range bin, every parameter N(mean, sigma) with AR(1) and the given innovation.
KpiModel single_bin_model(double mean, double sigma, double ar1, Innovation in) {
  KpiModel m = default_kpi_model();
  m.range_bin_edges = {0};
  m.visibility_bin_edges = {0};
  ClassModel c = m.classes["Car"];
  for (auto& e : c.errors) {
    e.mean = {mean};
    e.sigma = {sigma};
    e.visibility_std_scale = {1};
    e.ar1 = ar1;
    e.track_std = 0;
    e.innovation = in;
  }
  c.detection_probability = {{1.0}};
  c.false_positive_rate = 0;
  c.heading_flip_probability = 0;
  m.classes.clear();
  m.classes["Car"] = c;
  return m;
}

struct Stats {
  double mean = 0, std = 0, lag1 = 0;
};

// Per-object series -> pooled mean, std and lag-1 autocorrelation (about the pooled mean).
Stats stats(const std::vector<std::vector<double>>& series) {
  double n = 0, s = 0;
  for (const auto& v : series) n += v.size(), s += std::accumulate(v.begin(), v.end(), 0.0);
  const double mean = s / n;
  double ss = 0, cross = 0, nc = 0;
  for (const auto& v : series) {
    for (size_t t = 0; t < v.size(); ++t) {
      ss += (v[t] - mean) * (v[t] - mean);
      if (t > 0) cross += (v[t] - mean) * (v[t - 1] - mean), ++nc;
    }
  }
  const double var = ss / n;
  return {mean, std::sqrt(var), cross / nc / var};
}

std::vector<Object> cars(int n, double range) {
  std::vector<Object> v;
  for (int i = 0; i < n; ++i) {
    Object o;
    o.id = i + 1;
    o.cls = ObjectClass::Car;
    const double az = -0.6 + 1.2 * i / std::max(1, n - 1);
    o.position = {range * std::cos(az), range * std::sin(az), -0.9};
    o.size = {4, 1.8, 1.5};
    v.push_back(o);
  }
  return v;
}

void expect_injected_statistics(bool controller, Innovation in, std::uint64_t seed) {
  const double mean = 0.3, sigma = 0.4, ar1 = 0.6;
  KpiModel m = single_bin_model(mean, sigma, ar1, in);
  m.controller.enabled = controller;
  KpiManager kpi(m, seed);
  const auto truth = cars(10, 25);
  std::vector<std::vector<std::vector<double>>> series(kNumKpiParams, std::vector<std::vector<double>>(truth.size()));
  std::vector<Object> out;
  for (int f = 0; f < 10000; ++f) {
    kpi.apply(truth, out);
    for (const auto& inj : kpi.injections())
      for (int p = 0; p < kNumKpiParams; ++p) series[p][inj.truth_index].push_back(inj.error[p]);
  }
  for (int p = 0; p < kNumKpiParams; ++p) {
    const Stats s = stats(series[p]);
    SCOPED_TRACE(to_string(static_cast<KpiParam>(p)));
    EXPECT_NEAR(s.mean, mean, 0.05 * mean) << "mean within 5 %";
    EXPECT_NEAR(s.std, sigma, 0.05 * sigma) << "std within 5 %";
    EXPECT_NEAR(s.lag1, ar1, 0.05) << "lag-1 autocorrelation within 0.05";
  }
}

TEST(KpiManager, InjectedErrorsMatchMeanStdAndLag1Over10000FramesWithController) {
  expect_injected_statistics(true, {Innovation::Type::Mixture, 0, 0.05, 4}, 11);
}

TEST(KpiManager, InjectedErrorsMatchMeanStdAndLag1Over10000FramesStudentT) {
  expect_injected_statistics(true, {Innovation::Type::StudentT, 5, 0, 1}, 12);
  expect_injected_statistics(false, {Innovation::Type::Gaussian, 0, 0, 1}, 13);
}

TEST(KpiManager, MixtureInnovationsGiveHeavyTails) {
  // p = 0.05, scale 4: unit-variance mixture with excess kurtosis 3((1-p) + p r^4) s^4 - 3.
  const Innovation in{Innovation::Type::Mixture, 0, 0.05, 4};
  KpiRng rng(5);
  double m2 = 0, m4 = 0;
  const int n = 400000;
  for (int i = 0; i < n; ++i) {
    const double x = sample_innovation(in, rng);
    m2 += x * x;
    m4 += x * x * x * x;
  }
  m2 /= n;
  m4 /= n;
  EXPECT_NEAR(m2, 1.0, 0.02);
  EXPECT_NEAR(m4 / (m2 * m2) - 3, in.excess_kurtosis(), 0.15 * in.excess_kurtosis());
  EXPECT_GT(in.excess_kurtosis(), 5) << "the test needs a clearly heavy-tailed case";
}

TEST(KpiManager, ControllerBringsABiasedSourceBackOnTarget) {
  // A source with mean 0.5 and std 2 (a mis-specified generator): the controlled output must
  // settle at mean 0 and std 1 (within 5 % of the std, after a settling time of 5 windows).
  ControllerConfig cfg;
  RunningTargetController c(cfg);
  KpiRng rng(9);
  std::normal_distribution<double> src(0.5, 2.0);
  double z = 0;
  std::vector<double> tail;
  for (int i = 0; i < 60000; ++i) {
    z = 0.5 * z + std::sqrt(1 - 0.25) * src(rng);  // correlated too
    const double out = c.apply(z);
    if (i >= 10000) tail.push_back(out);
  }
  const Stats s = stats({tail});
  EXPECT_NEAR(s.mean, 0.0, 0.05);
  EXPECT_NEAR(s.std, 1.0, 0.05);
  // Without the controller the same source is far off: the controller is doing the work.
  ControllerConfig off = cfg;
  off.enabled = false;
  RunningTargetController o(off);
  EXPECT_NEAR(o.apply(3.0), 3.0, 1e-12);
}

TEST(KpiManager, MissesHaveTheTargetRateAndComeInBursts) {
  KpiModel m = single_bin_model(0, 0.1, 0.5, {});
  m.classes["Car"].detection_probability = {{0.8}};
  m.classes["Car"].miss_burst_mean = 4;
  KpiManager kpi(m, 21);
  const auto truth = cars(20, 30);
  std::vector<Object> out;
  long detected = 0, total = 0, runs = 0, run_frames = 0;
  std::vector<int> in_run(truth.size(), 0);
  for (int f = 0; f < 10000; ++f) {
    kpi.apply(truth, out);
    for (const auto& inj : kpi.injections()) {
      ++total;
      detected += inj.detected;
      int& r = in_run[inj.truth_index];
      if (!inj.detected) {
        if (r == 0) ++runs;
        ++r;
        ++run_frames;
      } else {
        r = 0;
      }
    }
  }
  EXPECT_NEAR(double(detected) / total, 0.8, 0.01);
  EXPECT_NEAR(double(run_frames) / runs, 4.0, 0.2) << "mean miss run length";
}

TEST(KpiManager, HeadingFlipsBy180DegreesAtTheConfiguredRate) {
  KpiModel m = single_bin_model(0, 0, 0, {});
  m.classes["Car"].heading_flip_probability = 0.1;
  m.classes["Car"].flip_burst_mean = 2;
  KpiManager kpi(m, 4);
  auto truth = cars(10, 15);
  for (auto& o : truth) o.heading = 0.3;
  std::vector<Object> out;
  long flips = 0, n = 0;
  for (int f = 0; f < 5000; ++f) {
    kpi.apply(truth, out);
    for (const auto& r : out) {
      ++n;
      const double d = std::remainder(r.heading - 0.3, 2 * M_PI);
      if (std::abs(std::abs(d) - M_PI) < 1e-9) ++flips;
      else EXPECT_NEAR(d, 0.0, 1e-9);
    }
  }
  EXPECT_NEAR(double(flips) / n, 0.1, 0.01);
}

TEST(KpiManager, FalsePositivesArePoissonAtTheConfiguredRate) {
  KpiModel m = single_bin_model(0, 0.1, 0.5, {});
  m.classes["Car"].false_positive_rate = 0.7;
  m.classes["Car"].fp_range_quantiles = {10, 50};
  m.classes["Car"].fp_azimuth_quantiles = {-0.5, 0.5};
  KpiManager kpi(m, 8);
  std::vector<Object> out;
  double n = 0, n2 = 0;
  const int frames = 20000;
  for (int f = 0; f < frames; ++f) {
    kpi.apply({}, out);
    n += out.size();
    n2 += double(out.size()) * out.size();
    for (const auto& o : out) {
      EXPECT_LE(o.id, -1000);
      const double r = o.position.head<2>().norm();
      EXPECT_TRUE(r >= 10 - 1e-9 && r <= 50 + 1e-9);
    }
  }
  const double mean = n / frames, var = n2 / frames - mean * mean;
  EXPECT_NEAR(mean, 0.7, 0.02);
  EXPECT_NEAR(var, 0.7, 0.05) << "Poisson: variance equals the mean";
}

TEST(KpiManager, PositionErrorsAreAlongAndAcrossTheLineOfSight) {
  // Hand-worked: a car straight to the left at (0, 10); along = +1 m (away from the sensor,
  // i.e. +y), across = +0.5 m (to the left of the line of sight, i.e. -x).
  KpiModel m = single_bin_model(0, 0, 0, {});
  auto& e = m.classes["Car"].errors;
  e[int(KpiParam::PositionAlong)].mean = {1.0};
  e[int(KpiParam::PositionAcross)].mean = {0.5};
  e[int(KpiParam::Length)].mean = {0.2};
  m.controller.enabled = false;
  KpiManager kpi(m, 1);
  Object o;
  o.id = 3;
  o.position = {0, 10, -1};
  o.size = {4, 2, 1.5};
  std::vector<Object> out;
  kpi.apply({o}, out);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_NEAR(out[0].position.x(), -0.5, 1e-12);
  EXPECT_NEAR(out[0].position.y(), 11.0, 1e-12);
  EXPECT_NEAR(out[0].position.z(), -1.0, 1e-12);
  EXPECT_NEAR(out[0].size.x(), 4.2, 1e-12);
  EXPECT_EQ(out[0].id, 3);
}

TEST(KpiManager, SizeErrorsAreNearlyConstantPerTrack) {
  KpiModel m = default_kpi_model();
  KpiManager kpi(m, 2);
  const auto truth = cars(30, 15);
  std::vector<Object> out;
  std::vector<std::vector<double>> len(truth.size());
  for (int f = 0; f < 300; ++f) {
    kpi.apply(truth, out);
    for (const auto& inj : kpi.injections()) len[inj.truth_index].push_back(inj.error[int(KpiParam::Length)]);
  }
  // Between-track spread (track_std 0.1) dominates the within-track spread (sigma 0.03).
  double within = 0, n = 0;
  std::vector<double> means;
  for (const auto& v : len) {
    const double mu = std::accumulate(v.begin(), v.end(), 0.0) / v.size();
    means.push_back(mu);
    for (double x : v) within += (x - mu) * (x - mu), ++n;
  }
  const Stats between = stats({means});
  EXPECT_NEAR(std::sqrt(within / n), 0.03, 0.006);
  EXPECT_GT(between.std, 0.06);
}

// --- the model file ---

std::filesystem::path temp_file(const std::string& name, const std::string& text) {
  const auto p = ::lidarsim::testing::temp_path("test_kpi_" + name);
  std::ofstream(p) << text;
  return p;
}

std::string error_of(const std::filesystem::path& p) {
  try {
    load_kpi_model(p);
  } catch (const Error& e) {
    return e.what();
  }
  return "(no error)";
}

TEST(KpiModelFile, RoundTripsThroughJson) {
  const KpiModel m = default_kpi_model();
  const auto p = ::lidarsim::testing::temp_path("test_kpi_roundtrip.json");
  save_kpi_model(m, p);
  const KpiModel r = load_kpi_model(p);
  EXPECT_EQ(kpi_model_to_json(r), kpi_model_to_json(m));
  EXPECT_EQ(r.classes.at("Car").errors[int(KpiParam::Heading)].innovation.type, Innovation::Type::StudentT);
  EXPECT_EQ(r.range_bin(39.9), 1);
  EXPECT_EQ(r.range_bin(1000), 3);
  EXPECT_EQ(r.visibility_bin(0.5), 1);
  EXPECT_EQ(r.find(ObjectClass::Truck), &r.classes.at("Car")) << "Truck falls back to Car";
}

TEST(KpiModelFile, UnreadableOrInvalidModelNamesFileAndField) {
  const std::string good = kpi_model_to_json(default_kpi_model());
  EXPECT_NE(error_of("/nonexistent/model.json").find("/nonexistent/model.json: (file): cannot open"), std::string::npos);

  const auto broken = temp_file("broken.json", good.substr(0, good.size() / 2));
  EXPECT_NE(error_of(broken).find("not valid JSON"), std::string::npos) << error_of(broken);

  auto edited = [&](const std::string& from, const std::string& to) {
    std::string s = good;
    const auto pos = s.find(from);
    EXPECT_NE(pos, std::string::npos) << from;
    return s.replace(pos, from.size(), to);
  };
  // A negative std.
  std::string neg = good;
  {
    auto j = nlohmann::json::parse(good);
    j["classes"]["Car"]["errors"]["position_along"]["std"][2] = -0.5;
    neg = j.dump();
  }
  const auto pn = temp_file("neg.json", neg);
  EXPECT_NE(error_of(pn).find(pn.string() + ": classes.Car.errors.position_along.std[2]: must be in [0, inf], got -0.5"),
            std::string::npos)
      << error_of(pn);
  // A missing field.
  {
    auto j = nlohmann::json::parse(good);
    j["classes"]["Pedestrian"]["errors"].erase("heading");
    const auto p = temp_file("missing.json", j.dump());
    EXPECT_NE(error_of(p).find("classes.Pedestrian.errors.heading: missing"), std::string::npos) << error_of(p);
  }
  // A non-finite number: JSON has no NaN/Inf literal, 1e999 overflows and is refused.
  {
    auto s = edited("\"miss_burst_mean\": 3", "\"miss_burst_mean\": 1e999");
    const auto p = temp_file("inf.json", s);
    EXPECT_NE(error_of(p).find(p.string() + ": (document): not valid JSON"), std::string::npos) << error_of(p);
    EXPECT_NE(error_of(p).find("overflow"), std::string::npos) << error_of(p);
  }
  // A string where a number belongs.
  {
    auto j = nlohmann::json::parse(good);
    j["classes"]["Car"]["miss_burst_mean"] = "three";
    const auto p = temp_file("str.json", j.dump());
    EXPECT_NE(error_of(p).find("classes.Car.miss_burst_mean: must be a number"), std::string::npos) << error_of(p);
  }
  // A probability out of range and a wrong number of bins.
  {
    auto j = nlohmann::json::parse(good);
    j["classes"]["Car"]["detection_probability"][0][1] = 1.5;
    const auto p = temp_file("prob.json", j.dump());
    EXPECT_NE(error_of(p).find("classes.Car.detection_probability[0][1]: must be in [0, 1], got 1.5"), std::string::npos)
        << error_of(p);
    j = nlohmann::json::parse(good);
    j["classes"]["Car"]["errors"]["width"]["mean"] = {0.0, 0.1};
    const auto q = temp_file("bins.json", j.dump());
    EXPECT_NE(error_of(q).find("classes.Car.errors.width.mean: must have 4 entries, got 2"), std::string::npos)
        << error_of(q);
    j = nlohmann::json::parse(good);
    j["classes"]["Car"]["errors"]["width"]["innovation"]["type"] = "cauchy";
    const auto r = temp_file("innov.json", j.dump());
    EXPECT_NE(error_of(r).find("classes.Car.errors.width.innovation.type: must be"), std::string::npos) << error_of(r);
  }
}

}  // namespace
}  // namespace lidarsim::sensor
