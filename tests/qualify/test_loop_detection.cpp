// The object loop when the hidden effect is on detection: the reference sensor's azimuth_dropout
// (a soiled left part of the window, detection probability x 0.2 for azimuth >= 20 deg) must be named
// first with target "detection", written into the KPI model as its conditional term on
// detection probability, and the KPI manager with that model must reproduce the measured
// detection rate in the sector. A 0/1 residual keeps a Bernoulli floor, so the bar is
// after <= 0.9 x before (not the error targets' 0.7). Four sequences of 48 tracks: with the
// default two of 24, the base model's [range][visibility] detection cells, fitted on one sequence,
// are too noisy for the sector rate to carry over to the held-out one.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <string>

#include "data/reference_sensor.h"
#include "qualify/objects/objects.h"
#include "sensor/kpi_fit.h"

namespace fs = std::filesystem;
using namespace lidarsim;

namespace {

fs::path fresh_dir(const std::string& name) {
  const fs::path p = fs::temp_directory_path() / ("lidarsim_qualify_det_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(p);
  return p;
}

struct LoopRun {
  nlohmann::json report;
  qualify::TrackingData data;
  sensor::KpiModel model;  // the refitted model the loop wrote
};

LoopRun loop_on(data::ObjectEffect effect) {
  const fs::path dir = fresh_dir(data::to_string(effect)), model = fresh_dir(data::to_string(effect) + "_model.json");
  data::ReferenceTrackingOptions o;
  o.effect = effect;
  o.seed = 17;
  o.sequences = 4;
  o.tracks = 48;
  data::write_reference_tracking(dir, o);
  qualify::LoopOptions lo;
  lo.out_model = model;
  LoopRun r;
  r.data = qualify::load_tracking(dir, "", "pointrcnn", 2);
  r.report = qualify::loop_objects(r.data, lo);
  r.model = sensor::load_kpi_model(model);  // validated on load
  fs::remove_all(dir);
  fs::remove(model);
  return r;
}

bool in_sector(const qualify::ObjectRecord& r) {
  const double az = r.feature[1];  // kObjectFeatures[1] == "azimuth"
  return az >= data::kDropoutAzimuthLo && az <= data::kDropoutAzimuthHi;
}

// Detection rate of the records inside / outside the sector.
std::array<double, 2> sector_rates(const qualify::ObjectSet& set) {
  double k[2] = {0, 0}, n[2] = {0, 0};
  for (const auto& r : set.records) {
    const int b = in_sector(r) ? 0 : 1;
    k[b] += r.detected, ++n[b];
  }
  return {n[0] ? k[0] / n[0] : -1, n[1] ? k[1] / n[1] : -1};
}

// Simulated detection rate in the sector: the KPI manager with `model` on the ground truth of
// every sequence, averaged over 4 seeds (misses are bursty draws).
std::array<double, 2> simulated_sector_rates(const qualify::TrackingData& data, const sensor::KpiModel& model) {
  std::vector<int> all;
  for (size_t s = 0; s < data.calib.size(); ++s) all.push_back(static_cast<int>(s));
  std::array<double, 2> sum{0, 0};
  for (std::uint64_t seed = 1; seed <= 4; ++seed) {
    const auto sim = sensor::resimulate(data.calib, model, seed);
    const auto r = sector_rates(qualify::collect_objects(data, all, &sim));
    sum[0] += r[0] / 4, sum[1] += r[1] / 4;
  }
  return sum;
}

}  // namespace

TEST(LoopDetectionStatistical, NamesAzimuthDropoutOnDetectionAddsItToTheKpiModelAndReproducesTheSectorRate) {
  const LoopRun run = loop_on(data::ObjectEffect::AzimuthDropout);
  const nlohmann::json& j = run.report;
  std::cout << "  ranking " << j["ranking"].dump().substr(0, 240) << "\n  before " << j["before"] << " after "
            << j["after"] << "; simulated before " << j["before_simulated"] << " after " << j["after_simulated"]
            << " (ratio " << j["after_simulated"].get<double>() / j["before_simulated"].get<double>() << ")\n";
  ASSERT_FALSE(j["ranking"].empty());
  EXPECT_EQ(j["ranking"][0]["feature"], "azimuth") << j["ranking"].dump();
  EXPECT_EQ(j["ranking"][0]["target"], "detection");
  EXPECT_EQ(j["added_effect"], "azimuth");
  EXPECT_EQ(j["model_term"], "azimuth");
  EXPECT_EQ(j["model_term_on"], "detection_probability");
  EXPECT_FALSE(j.contains("model_term_absent_because")) << j["model_term_absent_because"];
  // With the base model the KPI manager uses exactly the probability the loop's residual subtracts.
  EXPECT_NEAR(j["before_simulated"].get<double>(), j["before"].get<double>(), 1e-9);
  EXPECT_LE(j["after_simulated"].get<double>(), 0.9 * j["before_simulated"].get<double>());
  // The manager clamps the probability to [0, 1], the loop's table does not; clamping can only
  // bring p nearer a 0/1 outcome, so the simulated RMS is at most the loop's, and close to it.
  EXPECT_LE(j["after_simulated"].get<double>(), j["after"].get<double>() + 1e-12);
  EXPECT_GE(j["after_simulated"].get<double>(), j["after"].get<double>() - 0.05 * j["before"].get<double>());

  // The written model carries the term on detection (per class, azimuth), not on any error.
  for (const auto& [name, c] : run.model.classes) {
    EXPECT_EQ(c.detection_conditional.feature, "azimuth") << name;
    for (const auto& e : c.errors) EXPECT_FALSE(e.conditional.present()) << name;
  }
  // In the sector the Car term takes the probability down by most of the dropout (0.95 -> 0.19),
  // as a shift (rate_window) or a gain (rate_gain: cell x scale + bias).
  const auto& ct = run.model.classes.at("Car").detection_conditional;
  auto at = [&](double az) {
    const int b = ct.bin(az);
    return 0.95 * (ct.scale.empty() ? 1.0 : ct.scale[b]) + ct.bias[b];
  };
  EXPECT_LT(at(data::kDropoutAzimuthLo + 0.4), 0.55);
  EXPECT_GT(at(-0.5), 0.85) << "right of the sensor: no dropout";

  // The KPI manager with the refitted model reproduces the measured detection rate: outside the
  // sector within 0.05; inside it closes at least 3/4 of the base model's gap (measured: 0.88
  // of it). Not within 0.05 there: the equal-count azimuth bin that straddles the 20 deg edge
  // mixes dropout and clean objects, so the simulated sector rate stays ~0.06 high.
  std::vector<int> all;
  for (size_t s = 0; s < run.data.calib.size(); ++s) all.push_back(static_cast<int>(s));
  const auto measured = sector_rates(qualify::collect_objects(run.data, all));
  const auto refitted = simulated_sector_rates(run.data, run.model);
  std::vector<sensor::CalibrationSequence> fit_seqs;
  for (size_t s = 0; s < run.data.calib.size(); s += 2) fit_seqs.push_back(run.data.calib[s]);
  const auto base = simulated_sector_rates(run.data, sensor::fit_kpi_model(fit_seqs, {}));
  std::cout << "  detection rate in the sector: measured " << measured[0] << ", simulated refitted " << refitted[0]
            << ", base " << base[0] << "; outside: measured " << measured[1] << ", refitted " << refitted[1]
            << ", base " << base[1] << "\n";
  EXPECT_GT(base[0] - measured[0], 0.3) << "the base model does not know the dropout";
  EXPECT_LE(std::abs(refitted[0] - measured[0]), 0.25 * std::abs(base[0] - measured[0]));
  EXPECT_NEAR(refitted[1], measured[1], 0.05);
}

TEST(LoopDetectionStatistical, ControlWithoutHiddenEffectWritesNoTerm) {
  const LoopRun run = loop_on(data::ObjectEffect::None);
  const nlohmann::json& j = run.report;
  std::cout << "  control ranking " << j["ranking"].dump().substr(0, 160) << "\n";
  EXPECT_TRUE(j["added_effect"].is_null()) << j["ranking"].dump();
  EXPECT_TRUE(j["model_term"].is_null());
  EXPECT_EQ(j["before"], j["after"]);
  EXPECT_EQ(j["before_simulated"], j["after_simulated"]);
  for (const auto& [name, c] : run.model.classes) {
    EXPECT_FALSE(c.detection_conditional.present()) << name;
    for (const auto& e : c.errors) EXPECT_FALSE(e.conditional.present()) << name;
  }
}
