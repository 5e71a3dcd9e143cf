// False positives need no truth: a class with too few matched
// detections on one fold's fit sequences is left out of that fold's base KPI model (kpi_fit's
// min_samples; KITTI has many sequences without a pedestrian or a cyclist), yet its false positives
// are there. The false-positive analysis must still model them from the fit split's false positives,
// or that fold's held-out false positives of the class sit at the floor under every candidate, an
// equal and huge deviance that drowns a cell of extra false positives in that class (it scored ~0).
// The set: the reference sensor's 4 sequences; the even ones (fold 0's fit side) lose their
// pedestrians (labels and their detections), and every sequence gets Pedestrian false positives,
// spread plus (or not) a cell.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <iostream>
#include <random>
#include <sstream>
#include <string>

#include "common/angles.h"
#include "common/atomic_file.h"
#include "data/reference_sensor.h"
#include "qualify/objects/object_folds.h"
#include "qualify/objects/objects.h"
#include "sensor/kpi_model.h"
#include "tests/support/temp_path.h"

namespace fs = std::filesystem;
using namespace lidarsim;

namespace {

using lidarsim::kPi;
constexpr int kFrames = 200;
constexpr double kCellRangeLo = 15, kCellRangeHi = 25, kCellAzLo = -35 * kPi / 180, kCellAzHi = -15 * kPi / 180;

// An AB3DMOT Pedestrian line at (range, azimuth) in the reference sensor's frame (its calibration:
// camera x = -y, camera y = -z, camera z = x; the box's bottom on the ground 1.73 m below).
std::string pedestrian_fp(int frame, double range, double az, double score) {
  char line[160];
  std::snprintf(line, sizeof line, "%d,1,0,0,100,100,%.3f,1.7,0.6,0.8,%.4f,1.73,%.4f,0,-10\n", frame, score,
                -range * std::sin(az), range * std::cos(az));
  return line;
}

fs::path write_set(double cell_rate, const std::string& tag) {
  const fs::path dir = lidarsim::testing::temp_path("fp_missing_class_" + tag);
  data::ReferenceTrackingOptions o;
  o.sequences = 4, o.frames = kFrames, o.tracks = 24, o.seed = 29, o.false_positives = 0.6, o.polar_clutter = true;
  data::write_reference_tracking(dir, o);
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> U(0, 1);
  for (const std::string seq : {"0000", "0001", "0002", "0003"}) {
    const bool strip = seq == "0000" || seq == "0002";
    if (strip) {  // no pedestrians: the labels lose them, the Pedestrian detections are rewritten below
      const fs::path labels = dir / "label_02" / (seq + ".txt");
      std::ifstream in(labels);
      std::string kept, line;
      while (std::getline(in, line)) {
        std::istringstream ss(line);
        std::string frame, id, type;
        ss >> frame >> id >> type;
        if (type != "Pedestrian") kept += line + "\n";
      }
      in.close();
      write_file_atomically(labels, kept);
    }
    const fs::path path = dir / "detection" / "pointrcnn_Pedestrian_val" / (seq + ".txt");
    std::string dets;
    if (!strip) {
      std::ifstream d(path);
      std::stringstream all;
      all << d.rdbuf();
      dets = all.str();
    }
    for (int f = 0; f < kFrames; ++f) {
      for (int k = std::poisson_distribution<int>(0.15)(rng); k > 0; --k)
        dets += pedestrian_fp(f, 5 + 45 * U(rng), (-45 + 90 * U(rng)) * kPi / 180, 0.5 + 3.5 * U(rng));
      for (int k = cell_rate > 0 ? std::poisson_distribution<int>(cell_rate)(rng) : 0; k > 0; --k)
        dets += pedestrian_fp(f, kCellRangeLo + (kCellRangeHi - kCellRangeLo) * U(rng),
                              kCellAzLo + (kCellAzHi - kCellAzLo) * U(rng), 0.5 + 3.5 * U(rng));
    }
    write_file_atomically(path, dets);
  }
  return dir;
}

// What the test is about: fold 0 (fit on the even sequences) has no Pedestrian in its base model,
// fold 1 has.
void expect_pedestrian_missing_in_fold0(const qualify::TrackingData& data) {
  std::array<qualify::obj::Fold, 2> folds;
  qualify::obj::make_fold(folds[0], data, {0, 2}, {1, 3}, {});
  qualify::obj::make_fold(folds[1], data, {1, 3}, {0, 2}, {});
  EXPECT_EQ(folds[0].base.classes.count("Pedestrian"), 0u);
  EXPECT_EQ(folds[1].base.classes.count("Pedestrian"), 1u);
}

}  // namespace

TEST(LoopFalsePositivesStatistical, PedestrianCellIsAddedWhenAFoldsBaseModelHasNoPedestrian) {
  const fs::path dir = write_set(0.7, "cell");
  const qualify::TrackingData data = qualify::load_tracking(dir, "", "pointrcnn", 2);
  expect_pedestrian_missing_in_fold0(data);
  qualify::LoopOptions lo;
  lo.out_model = dir / "model.json";
  const nlohmann::json report = qualify::loop_objects(data, lo);
  const nlohmann::json& fp = report["false_positives"];
  for (const auto& c : fp["candidates"])
    std::cout << "  " << c["feature"] << " " << c["kind"] << " score " << c["score"] << " error " << c["error_before"]
              << " -> " << c["error_after"] << ": " << c["decision"] << "\n";
  ASSERT_FALSE(fp["added"].is_null());
  const std::string named = fp["added"]["feature"];
  EXPECT_TRUE(named == "azimuth" || named == "range") << named;
  EXPECT_EQ(fp["added"]["class"], "Pedestrian");
  // The held-out deviance falls beyond its bootstrap interval, and the rate error with it (not to 0.7 of
  // it on this little data: the cell's placement is fitted from 400 frames).
  EXPECT_LT(fp["added"]["change_interval95"][1].get<double>(), 0);
  EXPECT_LT(fp["added"]["error_after"].get<double>(), fp["added"]["error_before"].get<double>());
  // The written model (fitted on both sequences, where Pedestrian is modelled) carries the table.
  const sensor::KpiModel m = sensor::load_kpi_model(lo.out_model);
  EXPECT_TRUE(m.classes.at("Pedestrian").fp_table.present());
}

TEST(LoopFalsePositivesStatistical, PedestrianWithoutCellAddsNothingWhenAFoldsBaseModelHasNoPedestrian) {
  const fs::path dir = write_set(0, "control");
  const qualify::TrackingData data = qualify::load_tracking(dir, "", "pointrcnn", 2);
  expect_pedestrian_missing_in_fold0(data);
  const nlohmann::json report = qualify::loop_objects(data, {});
  EXPECT_TRUE(report["false_positives"]["added"].is_null()) << report["false_positives"]["added"].dump();
}
