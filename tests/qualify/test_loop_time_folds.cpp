// The object loop with few sequences: the features fixed to the sensor (azimuth) are
// judged on folds of time blocks within each sequence, tracks kept whole, so a detection dropout
// in a window of azimuth is found with two sequences; a candidate the held-out data cannot judge
// is reported as "the data cannot decide", never as ruled out.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <iostream>
#include <map>
#include <set>
#include <string>

#include "common/angles.h"
#include "data/reference_sensor.h"
#include "qualify/objects/object_folds.h"
#include "qualify/objects/objects.h"

namespace fs = std::filesystem;
using namespace lidarsim;

namespace {

using lidarsim::kDeg;

fs::path reference_data(const std::string& tag, const data::ReferenceTrackingOptions& o) {
  const fs::path dir =
      fs::temp_directory_path() / ("lidarsim_qualify_time_folds_" + tag + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  data::write_reference_tracking(dir, o);
  return dir;
}

nlohmann::json folds_loop_on(const std::string& tag, const data::ReferenceTrackingOptions& o) {
  const fs::path dir = reference_data(tag, o);
  qualify::LoopOptions lo;
  lo.distribution_seeds = 16;  // only the further error terms' check uses them
  const nlohmann::json j = qualify::loop_objects(qualify::load_tracking(dir, "", "pointrcnn", 2), lo);
  fs::remove_all(dir);
  return j;
}

}  // namespace

// Every track of the three classes lies whole in one block, with all its frames; each is held out
// by exactly one fold; and the blocks' records are the whole sequences' records.
TEST(LoopTimeFolds, TimeBlocksNeverSplitATrackAndHoldEachTrackOutOnce) {
  data::ReferenceTrackingOptions o;
  o.sequences = 2;
  o.tracks = 24;
  o.frames = 150;
  o.seed = 5;
  const fs::path dir = reference_data("blocks", o);
  const qualify::TrackingData data = qualify::load_tracking(dir, "", "pointrcnn", 2);
  fs::remove_all(dir);
  const qualify::obj::TimeBlocks tb = qualify::obj::split_into_time_blocks(data, 4);
  ASSERT_EQ(tb.data.calib.size(), 8u);
  ASSERT_EQ(tb.data.kitti.size(), 8u);
  ASSERT_EQ(tb.origin.size(), 8u);

  const qualify::ObjectSet whole = qualify::collect_objects(data, {0, 1});
  std::vector<int> blocks(tb.data.calib.size());
  for (size_t i = 0; i < blocks.size(); ++i) blocks[i] = static_cast<int>(i);
  const qualify::ObjectSet cut = qualify::collect_objects(tb.data, blocks);
  ASSERT_EQ(cut.records.size(), whole.records.size()) << "every truth object in exactly one block";

  using Key = std::array<int, 3>;  // sequence, track, frame
  std::map<Key, const qualify::ObjectRecord*> by_key;
  std::map<std::pair<int, int>, int> frames_whole;
  for (const auto& r : whole.records) by_key[{r.seq, r.track, r.frame}] = &r, ++frames_whole[{r.seq, r.track}];
  std::map<std::pair<int, int>, std::set<int>> track_blocks;  // (sequence, track) -> blocks holding it
  std::map<std::pair<int, int>, int> frames_cut;
  for (const auto& r : cut.records) {
    const int s = tb.origin[r.seq];
    track_blocks[{s, r.track}].insert(r.seq);
    ++frames_cut[{s, r.track}];
    const auto it = by_key.find({s, r.track, r.frame});
    ASSERT_NE(it, by_key.end()) << "block " << r.seq << " track " << r.track << " frame " << r.frame;
    const qualify::ObjectRecord& w = *it->second;
    EXPECT_EQ(r.detected, w.detected) << "the matching is the whole sequence's";
    for (int t = 0; t < qualify::kObjectTargetCount; ++t)
      if (!std::isnan(w.value[t])) {
        EXPECT_EQ(r.value[t], w.value[t]);
      }
    EXPECT_EQ(r.feature, w.feature) << "features from the whole track";
  }
  ASSERT_EQ(track_blocks.size(), frames_whole.size());
  const auto sides = qualify::obj::time_block_sides(tb);
  std::array<int, 2> side_tracks{};
  for (const auto& [track, in] : track_blocks) {
    EXPECT_EQ(in.size(), 1u) << "track " << track.second << " of sequence " << track.first << " split";
    EXPECT_EQ(frames_cut[track], frames_whole[track]) << "every frame of the track in its block";
    // Fold 1 holds out sides[1], fold 2 sides[0]: exactly one of them holds the track.
    int held = 0;
    for (int k = 0; k < 2; ++k) {
      const auto& side = sides[1 - k];
      const bool here = std::find(side.begin(), side.end(), *in.begin()) != side.end();
      held += here;
      side_tracks[k] += here;
    }
    EXPECT_EQ(held, 1) << "track " << track.second << " of sequence " << track.first;
  }
  // Both folds hold out tracks of both sequences, about half each.
  EXPECT_GT(side_tracks[0], 12);
  EXPECT_GT(side_tracks[1], 12);
  for (const auto& side : sides) {
    std::set<int> seqs;
    for (int b : side) seqs.insert(tb.origin[b]);
    EXPECT_EQ(seqs.size(), 2u);
  }
}

// With two or three sequences one fold holds a single sequence: the features that can depend on
// the place get "the data cannot decide", not "ruled out"; azimuth, fixed to the sensor, is judged
// on time blocks.
TEST(LoopTimeFolds, ReportsThatTheDataCannotDecideWithOneSequencePerFold) {
  for (int sequences : {2, 3}) {
    SCOPED_TRACE(std::to_string(sequences) + " sequences");
    data::ReferenceTrackingOptions o;
    o.sequences = sequences;
    o.tracks = 16;
    o.frames = 120;
    o.seed = 7;
    const nlohmann::json j = folds_loop_on("undecided", o);
    ASSERT_TRUE(j["candidates"].is_array());
    int undecided = 0, time_blocks = 0;
    for (const auto& c : j["candidates"]) {
      const std::string feature = c["feature"], decision = c["decision"], folds = c.value("folds", "");
      if (feature == "azimuth" || feature == "range") {  // fixed to the sensor (object_folds.h)
        EXPECT_EQ(folds, "time blocks") << c.dump();
        ++time_blocks;
      } else {
        EXPECT_EQ(folds, "sequences") << c.dump();
        EXPECT_NE(decision.rfind("ruled out", 0), 0u) << c.dump();
      }
      if (feature == "radial_velocity" && decision != "added") {
        EXPECT_EQ(decision.rfind("the data cannot decide: 1 sequence per fold", 0), 0u) << c.dump();
        ++undecided;
      }
    }
    EXPECT_GT(undecided, 0);
    EXPECT_GT(time_blocks, 0);
    EXPECT_TRUE(j["added_effect"].is_null()) << j["ranking"].dump();
  }
}

// A patch of dirt on the front left of the window (detection x 0.2 for azimuth in [8, 26] deg),
// two sequences: azimuth is judged on the time-block folds (each holds half the tracks of both
// sequences), names the window on detection and cuts the held-out deviance to <= 0.7.
TEST(LoopTimeFoldsStatistical, NamesAzimuthWindowOfDetectionDropoutWithTwoSequencesAndCutsDevianceBelow70Percent) {
  data::ReferenceTrackingOptions o;
  o.effect = data::ObjectEffect::AzimuthWindowDropout;
  o.window_azimuth_lo = 8 * kDeg;
  o.window_azimuth_hi = 26 * kDeg;
  o.sequences = 2;
  o.tracks = 48;
  o.frames = 200;
  o.seed = 31;
  const nlohmann::json j = folds_loop_on("window", o);
  std::cout << "  top " << j["ranking"][0].dump() << "\n  added " << j["added_effect"] << " " << j["error_metric"]
            << " " << j["error_before"] << " -> " << j["error_after"] << "\n";
  ASSERT_FALSE(j["ranking"].empty());
  EXPECT_EQ(j["ranking"][0]["feature"], "azimuth") << j["ranking"].dump();
  EXPECT_EQ(j["ranking"][0]["target"], "detection");
  EXPECT_EQ(j["added_effect"], "azimuth");
  EXPECT_EQ(j["error_metric"], "deviance per object");
  EXPECT_LE(j["error_after"].get<double>(), 0.7 * j["error_before"].get<double>());
  EXPECT_EQ(j.value("fold_scheme", ""), "time blocks");
}
