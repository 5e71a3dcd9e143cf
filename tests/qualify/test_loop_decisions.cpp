// The object loop records each candidate's decision when it is made (qualify/objects/object_loop.h
// ObjectLoopResult), with a reason a user acts on, and the JSON is written from that result. A
// refusal names the rule that really applied: "at most one bias form per target" only where a
// better bias form on the same target was tried first.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <iostream>
#include <string>

#include "data/reference_sensor.h"
#include "qualify/objects/object_loop.h"
#include "qualify/objects/objects.h"

namespace fs = std::filesystem;
using namespace lidarsim;
using qualify::obj::DecisionKind;

namespace {

const std::string kOnePerTarget = "not added: at most one bias form per target is added per run";

bool starts_with(const std::string& s, const std::string& p) { return s.rfind(p, 0) == 0; }
bool is_spread(const nlohmann::json& c) { return starts_with(c["kind"].get<std::string>(), "spread_"); }

qualify::TrackingData reference(const std::string& tag, data::ObjectEffect effect, data::ObjectEffect second,
                                int sequences = 2, int tracks = 24, std::uint64_t seed = 17) {
  const fs::path dir = fs::temp_directory_path() / ("lidarsim_qualify_decisions_" + tag + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  data::ReferenceTrackingOptions o;
  o.effect = effect;
  o.second_effect = second;
  o.seed = seed;
  o.sequences = sequences;
  o.tracks = tracks;
  data::write_reference_tracking(dir, o);
  qualify::TrackingData d = qualify::load_tracking(dir, "", "pointrcnn", 2);
  fs::remove_all(dir);
  return d;
}

// Every candidate has a decision and a reason; the one-per-target refusal is given only to a bias
// form whose target has a better bias form that was added or judged (its decision "added" or
// "rejected..."), or that ranks first and was itself stopped by max_effects.
void expect_true_refusals(const nlohmann::json& j) {
  const nlohmann::json& cands = j["candidates"];
  ASSERT_TRUE(cands.is_array());
  for (const auto& c : cands) {
    EXPECT_FALSE(c.value("reason", "").empty()) << c.dump();
    EXPECT_NE(c["decision"], "undecided") << c.dump();
    if (!starts_with(c["decision"], kOnePerTarget)) continue;
    EXPECT_FALSE(is_spread(c)) << "a spread form refused by the bias forms' rule: " << c.dump();
    bool better_first = false;
    for (const auto& o : cands) {
      if (o["target"] != c["target"] || is_spread(o) || o["score"].get<double>() <= c["score"].get<double>()) continue;
      const std::string d = o["decision"];
      better_first |= d == "added" || starts_with(d, "rejected") || starts_with(d, "not tried: the most bias forms");
    }
    EXPECT_TRUE(better_first) << "refused by one-per-target, but no better bias form on its target came first: "
                              << c.dump();
  }
}

}  // namespace

// Two effects on two targets (length by truncation, across by aspect) with at most one effect per
// run: the one ranked second is not tried because of max_effects, and says so; the old loop
// refused it with "at most one bias form per target", which no other form on its target had taken.
TEST(LoopDecisionsStatistical, AFurtherEffectStoppedByMaxEffectsSaysSoNotOnePerTarget) {
  const qualify::TrackingData data =
      reference("max1", data::ObjectEffect::TruncationSize, data::ObjectEffect::AspectAcross);
  qualify::LoopOptions lo;
  lo.max_effects = 1;
  lo.distribution_seeds = 16;
  const nlohmann::json j = qualify::loop_objects(data, lo);
  ASSERT_EQ(j["added_effects"].size(), 1u) << j["added_effects"].dump();
  // Either planted effect may rank first (the aspect one does as a line, the truncation one as a
  // table); the other one is the further effect max_effects stops.
  const std::string first = j["added_effects"][0]["target"];
  ASSERT_TRUE(first == "length" || first == "position_across") << first;
  const std::string other = first == "length" ? "position_across" : "length";
  const nlohmann::json* further = nullptr;  // the best bias form on the other planted target
  for (const auto& c : j["candidates"])
    if (c["target"] == other && !is_spread(c) && !starts_with(c["decision"].get<std::string>(), "not ranked") &&
        (!further || c["score"].get<double>() > (*further)["score"].get<double>()))
      further = &c;
  ASSERT_NE(further, nullptr);
  std::cout << "  " << further->dump() << "\n";
  EXPECT_EQ((*further)["feature"], other == "length" ? "truncation" : "heading_to_line_of_sight");
  EXPECT_TRUE(starts_with((*further)["decision"], "not tried: the most bias forms per run")) << further->dump();
  EXPECT_NE((*further)["reason"].get<std::string>().find("--max-effects 1"), std::string::npos) << further->dump();
  expect_true_refusals(j);
}

// The typed result, on a spread that grows with aspect (4 sequences): no candidate is left
// undecided, the JSON's decisions and reasons are the result's, the spread form added is the best
// one, and every other spread form that clears the threshold is "not tried: only the best spread
// form is tried per run" (the old loop refused them by the bias forms' rule).
TEST(LoopDecisionsStatistical, TheAddedSpreadFormsRivalsAreNotRefusedByTheBiasFormsRule) {
  const qualify::TrackingData data =
      reference("spread", data::ObjectEffect::AspectSpread, data::ObjectEffect::None, 4, 48, 23);
  qualify::LoopOptions lo;
  lo.distribution_seeds = 16;
  const qualify::obj::ObjectLoopResult r = qualify::obj::run_object_loop(data, lo);
  const nlohmann::json j = qualify::obj::report_json(r);
  ASSERT_EQ(r.decisions.size(), r.candidates.size());
  ASSERT_EQ(j["candidates"].size(), r.candidates.size());
  for (size_t i = 0; i < r.decisions.size(); ++i) {
    EXPECT_NE(r.decisions[i].kind, DecisionKind::Pending) << i;
    EXPECT_EQ(j["candidates"][i]["reason"], r.decisions[i].reason) << i;
    EXPECT_EQ(j["candidates"][i]["decision"], qualify::obj::decision_label(r.decisions[i], r.candidates[i])) << i;
  }
  ASSERT_TRUE(r.spread.has_value());
  EXPECT_EQ(r.spread->candidate, r.spread_ranking.front());
  EXPECT_EQ(r.decisions[r.spread->candidate].kind, DecisionKind::Added);
  EXPECT_EQ(j["added_effect"], "heading_to_line_of_sight");
  int rivals = 0;
  for (size_t i = 0; i < r.candidates.size(); ++i) {
    const qualify::obj::Candidate& c = r.candidates[i];
    if (!qualify::obj::is_spread(c.kind) || static_cast<int>(i) == r.spread->candidate) continue;
    if (c.score < lo.threshold || c.interval[0] <= 0 || qualify::obj::used_by_model(c)) continue;
    ++rivals;
    EXPECT_EQ(r.decisions[i].kind, DecisionKind::OneSpreadForm) << j["candidates"][i].dump();
  }
  EXPECT_GT(rivals, 0) << "the planted spread shows in more than one form";
  expect_true_refusals(j);
}
