// The planted-effect generator (data/planted_tracking.h) on the real KITTI tracking ground truth:
// parameters within their documented ranges, the same seed gives the same files, and what it writes
// is the reader's format with the source's truth and detections near it.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <set>
#include <sstream>

#include "common/error.h"
#include "data/kitti_tracking.h"
#include "data/planted_tracking.h"
#include "tests/support/shared_data.h"
#include "tests/support/temp_path.h"

namespace lidarsim::data {
namespace {

namespace fs = std::filesystem;
constexpr double kDeg = std::numbers::pi / 180;

PlantedTrackingOptions small(const fs::path& source, std::uint64_t seed, int sequences = 2) {
  PlantedTrackingOptions o;
  o.source = source, o.seed = seed, o.sequences = sequences, o.max_frames = 60;
  return o;
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

TEST(PlantedTracking, FamilyNamesRoundTripAndUnknownNamesListTheValidOnes) {
  for (int k = 0; k < kPlantedFamilies; ++k)
    EXPECT_EQ(planted_family_from_string(kPlantedFamilyNames[k]), static_cast<PlantedFamily>(k));
  try {
    planted_family_from_string("lagg");
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("valid: lag, aspect_size"), std::string::npos) << e.what();
  }
}

TEST(PlantedTracking, ParametersLieInTheirRangesAndWindowsWithinTheObjects) {
  LIDARSIM_REQUIRE_SHARED_DATA(source, "kitti-tracking-gt-pointrcnn");
  for (int k = 0; k < kPlantedFamilies; ++k)
    for (std::uint64_t seed = 1; seed <= 2; ++seed) {
      const auto fam = static_cast<PlantedFamily>(k);
      const PlantedDraw d = plan_planted_tracking(fam, small(source, seed, seed % 2 ? 2 : 4));
      SCOPED_TRACE(to_string(fam) + " seed " + std::to_string(seed));
      ASSERT_EQ(d.sequences.size(), seed % 2 ? 2u : 4u);
      std::set<std::string> names;
      for (const auto& s : d.sequences) {
        names.insert(s.name);
        EXPECT_EQ(s.frames, 60);
      }
      EXPECT_EQ(names.size(), d.sequences.size()) << "sequences drawn without replacement";
      EXPECT_LT(d.azimuth_lo, d.azimuth_hi);
      const PlantedEffect& e = d.effect;
      const auto& p = e.params;
      EXPECT_EQ(e.family, fam);
      EXPECT_EQ(e.feature.empty(), fam == PlantedFamily::Control);
      switch (fam) {
        case PlantedFamily::Lag:
          EXPECT_GE(p.at("lag_s"), 0.05); EXPECT_LE(p.at("lag_s"), 0.3);
          break;
        case PlantedFamily::AzimuthDropout: {
          const double w = p.at("azimuth_hi_deg") - p.at("azimuth_lo_deg");
          EXPECT_GE(w, 15); EXPECT_LE(w, 40);
          EXPECT_GE(p.at("azimuth_lo_deg") * kDeg, d.azimuth_lo - 1e-9);
          EXPECT_LE(p.at("factor"), 0.3);
          break;
        }
        case PlantedFamily::RangeDropout:
          EXPECT_GE(p.at("range_m"), d.range_lo); EXPECT_LE(p.at("range_m"), d.range_hi);
          break;
        case PlantedFamily::FpCell: {
          const double w = p.at("azimuth_hi_deg") - p.at("azimuth_lo_deg");
          EXPECT_GE(w, 10); EXPECT_LE(w, 30);
          EXPECT_GE(p.at("rate_per_frame"), 0.3); EXPECT_LE(p.at("rate_per_frame"), 1.0);
          EXPECT_EQ(e.target, kFalsePositivesTarget);
          break;
        }
        case PlantedFamily::ClassBias:
          EXPECT_GE(std::abs(p.at("amplitude")), 4 * 0.8 * 0.05 - 1e-12);  // 4 x the smallest sigma
          break;
        default: break;
      }
    }
}

TEST(PlantedTracking, SameSeedWritesTheSameFilesAndAnotherSeedDoesNot) {
  LIDARSIM_REQUIRE_SHARED_DATA(source, "kitti-tracking-gt-pointrcnn");
  const fs::path a = testing::temp_path("planted_a"), b = testing::temp_path("planted_b"),
                 c = testing::temp_path("planted_c");
  const PlantedDraw d = plan_planted_tracking(PlantedFamily::Lag, small(source, 7));
  write_planted_tracking(a, d);
  write_planted_tracking(b, plan_planted_tracking(PlantedFamily::Lag, small(source, 7)));
  write_planted_tracking(c, plan_planted_tracking(PlantedFamily::Lag, small(source, 8)));
  const std::string name = d.sequences[0].name;
  const fs::path det = fs::path("detection/pointrcnn_Car_val") / (name + ".txt");
  EXPECT_EQ(slurp(a / det), slurp(b / det));
  EXPECT_EQ(slurp(a / "evaluate_tracking.seqmap.val"), slurp(b / "evaluate_tracking.seqmap.val"));
  EXPECT_NE(slurp(a / "evaluate_tracking.seqmap.val") + slurp(a / det),
            slurp(c / "evaluate_tracking.seqmap.val") + (fs::exists(c / det) ? slurp(c / det) : ""));
}

// The written folder reads back with the reader: the window's truth is the source's (frames
// renumbered), and the detections lie near it (base errors of tenths of a metre) at a plausible rate.
TEST(PlantedTracking, WritesTheReadersFormatWithTheSourceTruthAndDetectionsNearIt) {
  LIDARSIM_REQUIRE_SHARED_DATA(source, "kitti-tracking-gt-pointrcnn");
  const fs::path dir = testing::temp_path("planted_read");
  const PlantedDraw d = plan_planted_tracking(PlantedFamily::Control, small(source, 3));
  write_planted_tracking(dir, d);
  EXPECT_EQ(read_kitti_seqmap(dir / "evaluate_tracking.seqmap.val").size(), 2u);
  for (const PlantedSequence& w : d.sequences) {
    const KittiTrackingSequence src = read_kitti_tracking_sequence(source, w.name, "none");
    const KittiTrackingSequence out = read_kitti_tracking_sequence(dir, w.name);
    ASSERT_EQ(static_cast<int>(out.frames.size()), w.frames);
    int truth = 0, detected = 0, near = 0;
    for (int f = 0; f < w.frames; ++f) {
      const auto& st = src.frames[w.first_frame + f].truth;
      const auto& ot = out.frames[f].truth;
      ASSERT_EQ(ot.size(), st.size()) << w.name << " frame " << f;
      for (size_t i = 0; i < ot.size(); ++i)
        EXPECT_LT((ot[i].object.position - st[i].object.position).norm(), 1e-9);
      for (const auto& t : ot) {
        if (t.type != "Car" && t.type != "Pedestrian" && t.type != "Cyclist") continue;
        ++truth;
        double best = 1e9;
        for (const auto& det : out.frames[f].detections)
          if (det.type == t.type) best = std::min(best, (det.object.position - t.object.position).norm());
        detected += best < 2.0;
        near += best < 1.0;
      }
    }
    ASSERT_GT(truth, 0);
    EXPECT_GT(double(detected) / truth, 0.6) << w.name;
    EXPECT_GT(double(near) / detected, 0.95) << w.name;
  }
}

// The ideal refit's error: lower than before for an effect on an error and on detection, none for a control.
TEST(PlantedTracking, IdealRefitLowersThePlantedTargetsErrorAndIsAbsentForAControl) {
  LIDARSIM_REQUIRE_SHARED_DATA(source, "kitti-tracking-gt-pointrcnn");
  for (PlantedFamily fam : {PlantedFamily::AspectSize, PlantedFamily::AzimuthDropout, PlantedFamily::Control}) {
    const PlantedStats s = write_planted_tracking(testing::temp_path("planted_ideal_" + to_string(fam)),
                                                  plan_planted_tracking(fam, small(source, 5)));
    if (fam == PlantedFamily::Control) {
      EXPECT_TRUE(std::isnan(s.ideal_before) && std::isnan(s.ideal_after));
    } else {
      EXPECT_LT(s.ideal_after, s.ideal_before) << to_string(fam);
      EXPECT_GT(s.ideal_after, 0) << to_string(fam);
    }
  }
}

TEST(PlantedTracking, TooFewUsableSequencesIsAnErrorNamingTheFolder) {
  LIDARSIM_REQUIRE_SHARED_DATA(source, "kitti-tracking-gt-pointrcnn");
  PlantedTrackingOptions o = small(source, 1, 40);
  try {
    plan_planted_tracking(PlantedFamily::Lag, o);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("kitti-tracking-gt-pointrcnn"), std::string::npos) << e.what();
  }
  EXPECT_THROW(plan_planted_tracking(PlantedFamily::Lag, small(testing::temp_path("nowhere"), 1)), Error);
}

}  // namespace
}  // namespace lidarsim::data
