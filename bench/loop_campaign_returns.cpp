// The return-rate half of the loop's campaign of random planted effects (issues 26, 27): measured
// HDL-64E scans (SemanticKITTI sequences 00 and 08, KITTI object frames, from ../shared/data), one
// dropout planted with random parameters (qualify/returns/returns_loop.h: a per-laser dropout, one class
// beyond a range, an azimuth window; controls), the loop (qualify::loop_returns) run blind, scored:
//   detect families  recall = the planted feature is the added effect AND the held-out deviance
//                    excess after <= 0.7 x before;
//   control          false add = anything added.
// The loop's base is fitted on the same scans before the plant (the model that was right before
// the sensor changed; each fold's base leaves the held-out scans out), so on a control the base
// is the truth up to its estimation error, and the loop must add nothing.
// Folds (--folds scan, the default): the scans of every planted place, assigned to 5 folds at
// random per draw, so each fold's fit holds scans of every drive. --folds place holds out whole
// places instead: no scenery is shared, but a held-out place's overall return rate is not
// predictable from the others, and on controls the loop then adds "class" (unlabelled cells,
// which are mostly seq08's and the KITTI object frames', return less), 5 of 10 controls.
// class_beyond_range needs semantic classes, which only seq00 has: it runs on seq00 alone (its six
// scans as folds), and every second control does too.
// Excess = held-out deviance per cell minus that of the oracle (the loop's own held-out base times
// the planted keep probability of each cell): the base's estimation error is in both and cancels,
// so the excess is the planted effect's part alone (the "above floor" of the other campaigns).
//   bench_loop_campaign_returns [--draws 10] [--seed 1] [--families a,b] [--folds scan|place] [--json out.json]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cxxopts.hpp>
#include <filesystem>
#include <map>
#include <sstream>

#include "common/atomic_file.h"
#include "common/error.h"
#include "data/import.h"
#include "pgm/materials.h"
#include "qualify/returns/returns_loop.h"

namespace fs = std::filesystem;
using namespace lidarsim;

namespace {

struct Place {
  std::string name;
  std::vector<pgm::PolarGridMap> maps;
  pgm::BeamLayout layout;
  std::vector<qualify::ReturnCell> reference;    // cells before the plant
  std::vector<std::vector<float>> class_ranges;  // return ranges per class
};

Place load_place(const std::string& name, const std::string& format, const std::vector<fs::path>& dirs) {
  const auto t0 = std::chrono::steady_clock::now();
  Place p;
  p.name = name;
  data::ImportOptions o;
  o.extra_channels = {"height"};
  o.include_unlabelled = true;
  for (const auto& dir : dirs) {
    const data::Dataset d = format == "semantickitti" ? data::import_semantickitti(dir, o) : data::import_kitti_object(dir, o);
    p.layout = d.layout;
    for (int f = 0; f < d.size(); ++f) p.maps.push_back(d.frame_pgm(f));
  }
  p.class_ranges.assign(pgm::class_count(), {});
  for (std::size_t s = 0; s < p.maps.size(); ++s) {
    const auto c = qualify::return_cells(pgm::return_target(p.maps[s]), p.layout, static_cast<int>(s));
    p.reference.insert(p.reference.end(), c.begin(), c.end());
    const float* range = p.maps[s].channel("range");
    const float* cls = p.maps[s].channel("class");
    const float* mask = p.maps[s].channel("mask");
    for (std::size_t i = 0; i < p.maps[s].cells(); ++i)
      if (mask[i] > 0.5f) p.class_ranges[std::clamp(static_cast<int>(cls[i]), 0, pgm::class_count() - 1)].push_back(range[i]);
  }
  std::fprintf(stderr, "loaded %s: %zu scans, %zu geometry cells, %.1f s\n", name.c_str(), p.maps.size(), p.reference.size(),
               std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  return p;
}

struct Rows {
  int draws = 0, hits = 0, false_adds = 0;
  std::vector<double> before, after, seconds;
  std::map<std::string, int> named;
};

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
}

// One draw: the effect planted on every scan of `ps` (a sensor effect is in every recording of the
// unit); folds are whole places when there are several (no shared scenery), else scans.
bool g_place_folds = false;

nlohmann::json run_draw(const std::vector<const Place*>& ps, qualify::PlantedReturnFamily family, std::uint64_t seed, Rows& rows) {
  const auto t0 = std::chrono::steady_clock::now();
  const Place& p0 = *ps.front();
  const auto effect = qualify::draw_planted_returns(family, seed, p0.layout.rows(), p0.class_ranges);
  std::vector<qualify::ReturnCell> cells, reference;
  qualify::ReturnLoopOptions o;
  o.fold_seed = seed;  // each draw its own fold assignment (controls differ only in it)
  long long dropped = 0;
  int scan = 0;
  std::string names;
  for (std::size_t g = 0; g < ps.size(); ++g) {
    const Place& p = *ps[g];
    names += (g ? "+" : "") + p.name;
    for (std::size_t s = 0; s < p.maps.size(); ++s, ++scan) {
      pgm::PolarGridMap m = p.maps[s];
      dropped += qualify::plant_returns(m, effect, seed, scan);
      const auto c = qualify::return_cells(pgm::return_target(m), p.layout, scan);
      cells.insert(cells.end(), c.begin(), c.end());
      if (ps.size() > 1 && g_place_folds) o.scan_group.push_back(static_cast<int>(g));
    }
    for (auto c : p.reference) {
      c.scan += scan - static_cast<int>(p.maps.size());
      reference.push_back(c);
    }
  }
  const auto r = qualify::loop_returns(cells, reference, p0.layout, o);
  std::vector<float> oracle(cells.size());
  for (std::size_t i = 0; i < cells.size(); ++i)
    oracle[i] = static_cast<float>(r.p_before[i] * effect.keep_at(cells[i].row, cells[i].range, cells[i].class_id, cells[i].azimuth_deg));
  const double d_oracle = qualify::mean_deviance(cells, oracle);
  const double before = r.deviance_before - d_oracle, after = r.deviance_after - d_oracle;
  const bool control = family == qualify::PlantedReturnFamily::Control;
  const bool named = !r.added_feature.empty() &&
                     std::find(effect.accepted.begin(), effect.accepted.end(), r.added_feature) != effect.accepted.end();
  const bool cut = after <= 0.7 * before;
  const bool hit = control ? r.added_feature.empty() : named && cut;
  const bool false_add = control ? !r.added_feature.empty() : !r.added_feature.empty() && !named;
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  ++rows.draws;
  rows.hits += hit;
  rows.false_adds += false_add;
  rows.before.push_back(before), rows.after.push_back(after), rows.seconds.push_back(seconds);
  ++rows.named[r.added_feature.empty() ? "-" : r.added_feature];
  std::fprintf(stderr, "  %-18s %-26s seed %-10llu dropped %7lld added %-13s excess %.5f -> %.5f %s (%.1f s)\n",
               qualify::to_string(family).c_str(), names.c_str(), static_cast<unsigned long long>(seed), dropped,
               r.added_feature.empty() ? "-" : r.added_feature.c_str(), before, after, hit ? "hit" : "MISS", seconds);
  nlohmann::json j = effect.parameters;
  j["places"] = names;
  j["dropped"] = dropped;
  j["added_effect"] = r.added_feature;
  j["deviance_before"] = r.deviance_before, j["deviance_after"] = r.deviance_after, j["deviance_oracle"] = d_oracle;
  j["excess_before"] = before, j["excess_after"] = after;
  j["named"] = named, j["cut"] = cut, j["hit"] = hit, j["false_add"] = false_add;
  nlohmann::json top = nlohmann::json::array();
  for (std::size_t k = 0; k < std::min<std::size_t>(3, r.candidates.size()); ++k)
    top.push_back({{"feature", r.candidates[k].feature}, {"form", to_string(r.candidates[k].form)}, {"score", r.candidates[k].score},
                   {"selection_lower", r.candidates[k].selection_lower}});
  j["ranking_top3"] = top;
  j["seconds"] = seconds;
  return j;
}

}  // namespace

int main(int argc, char** argv) try {
  cxxopts::Options opts("bench_loop_campaign_returns", "Random planted return dropouts on measured HDL-64E scans, the loop run blind, scored.");
  opts.add_options()("draws", "draws per family", cxxopts::value<int>()->default_value("10"))(
      "seed", "campaign seed", cxxopts::value<std::uint64_t>()->default_value("1"))(
      "families", "comma-separated families (default: all)", cxxopts::value<std::string>()->default_value(""))(
      "shared", "measured data folder (default: ../shared/data beside the source tree)", cxxopts::value<std::string>())(
      "folds", "scan (folds = scans of every place) | place (whole places)", cxxopts::value<std::string>()->default_value("scan"))(
      "json", "write every draw and the table here (atomically)", cxxopts::value<std::string>())("h,help", "show this help");
  const auto args = opts.parse(argc, argv);
  if (args.count("help")) {
    std::printf("%s\n", opts.help().c_str());
    return 0;
  }
  const fs::path source_dir = LIDARSIM_SOURCE_DIR;
  const fs::path shared = args.count("shared") ? fs::path(args["shared"].as<std::string>()) : source_dir / "../shared/data";
  const int draws = std::max(1, args["draws"].as<int>());
  g_place_folds = args["folds"].as<std::string>() == "place";
  const std::uint64_t seed = args["seed"].as<std::uint64_t>();
  std::vector<qualify::PlantedReturnFamily> families;
  {
    std::stringstream ss(args["families"].as<std::string>());
    for (std::string f; std::getline(ss, f, ',');)
      if (!f.empty()) families.push_back(qualify::planted_return_family_from_string(f));
    if (families.empty()) families = qualify::all_planted_return_families();
  }
  const auto t_load = std::chrono::steady_clock::now();
  std::vector<Place> places;
  places.push_back(load_place("seq00", "semantickitti", {shared / "semantickitti-seq00-sample"}));
  places.push_back(load_place("seq08", "semantickitti", {shared / "semantickitti-seq08-mos-sample"}));
  places.push_back(load_place("kitti-object", "kitti_object", {shared / "kitti-object-sample", shared / "kitti-object-more"}));
  const double load_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_load).count();

  const auto t0 = std::chrono::steady_clock::now();
  nlohmann::json all = nlohmann::json::array();
  std::vector<Rows> rows(families.size());
  for (std::size_t f = 0; f < families.size(); ++f) {
    std::fprintf(stderr, "%s: %d draws\n", qualify::to_string(families[f]).c_str(), draws);
    for (int d = 0; d < draws; ++d) {
      const std::uint64_t s = seed * 1000003ULL + static_cast<std::uint64_t>(families[f]) * 1000ULL + d;
      // Class beyond range needs semantic classes: only sequence 00 labels them (folds: its scans).
      // Controls alternate between the two settings (the three places; seq00 alone).
      std::vector<const Place*> ps = {&places[0]};
      const bool seq00_only = families[f] == qualify::PlantedReturnFamily::ClassBeyondRange ||
                              (families[f] == qualify::PlantedReturnFamily::Control && d % 2 == 1);
      if (!seq00_only) ps = {&places[0], &places[1], &places[2]};
      all.push_back(run_draw(ps, families[f], s, rows[f]));
    }
  }
  const double total_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::printf("Return-rate loop campaign: %d draws per family, seed %llu (places seq00, seq08, kitti-object; loading %.0f s)\n\n",
              draws, static_cast<unsigned long long>(seed), load_s);
  std::printf("| family | accepted names | draws | recall | false adds | median excess before | median excess after | median s | added effects |\n|---|---|---|---|---|---|---|---|---|\n");
  nlohmann::json table = nlohmann::json::array();
  int dd = 0, dh = 0, cd = 0, ca = 0;
  for (std::size_t f = 0; f < families.size(); ++f) {
    const auto& r = rows[f];
    const bool control = families[f] == qualify::PlantedReturnFamily::Control;
    const auto sample = qualify::draw_planted_returns(families[f], 0, places[0].layout.rows(), places[0].class_ranges);
    std::string acc, named;
    for (const auto& a : sample.accepted) acc += (acc.empty() ? "" : ", ") + a;
    for (const auto& [k, n] : r.named) named += (named.empty() ? "" : ", ") + k + " " + std::to_string(n);
    const std::string recall = control ? "-" : std::to_string(r.hits) + "/" + std::to_string(r.draws);
    std::printf("| %s | %s | %d | %s | %d | %.5f | %.5f | %.1f | %s |\n", qualify::to_string(families[f]).c_str(),
                acc.empty() ? "-" : acc.c_str(), r.draws, recall.c_str(), r.false_adds, median(r.before), median(r.after),
                median(r.seconds), named.c_str());
    table.push_back({{"family", qualify::to_string(families[f])}, {"draws", r.draws}, {"hits", r.hits},
                     {"false_adds", r.false_adds}, {"median_excess_before", median(r.before)},
                     {"median_excess_after", median(r.after)}, {"median_seconds", median(r.seconds)}, {"added_effects", r.named}});
    if (control) cd += r.draws, ca += r.false_adds;
    else dd += r.draws, dh += r.hits;
  }
  std::printf("\noverall: recall %d/%d (detect families), control false adds %d/%d; %.0f s for %zu draws\n", dh, dd, ca, cd,
              total_s, all.size());
  if (args.count("json")) {
    const nlohmann::json out = {{"seed", seed}, {"draws_per_family", draws},
                                {"overall", {{"detect_hits", dh}, {"detect_draws", dd}, {"control_false_adds", ca},
                                             {"control_draws", cd}, {"seconds", total_s}, {"load_seconds", load_s}}},
                                {"recall_rule", "added_effect in the accepted names and excess after <= 0.7 x before"},
                                {"excess", "held-out deviance per cell minus the oracle's (held-out base x planted keep)"},
                                {"table", table}, {"draws", all}};
    write_file_atomically(args["json"].as<std::string>(), out.dump(1));
    std::fprintf(stderr, "wrote %s\n", args["json"].as<std::string>().c_str());
  }
  return 0;
} catch (const std::exception& e) {
  std::fprintf(stderr, "error: %s\n", e.what());
  return 1;
}
